"""Composing configs exactly as `python train.py ...` does, and a tiny-run override set."""

import signal
from pathlib import Path

import torch
from hydra import compose, initialize_config_dir

from bfc.config import register

CONF = Path(__file__).resolve().parents[2] / "conf"
ROOT = CONF.parent

TINY = [
    "env.num_envs=16",
    "collector.frames_per_batch=512",
    "collector.total_frames=2048",
    "loss.num_minibatches=2",
    "loss.epochs=2",
    "eval.interval_frames=1024",
    "eval.num_starts=4",
    "eval.seconds=0.5",
    "eval.hold_seconds=0.2",
    "checkpoint.interval_frames=1024",
    "logger.progress=false",
    "env.num_threads=1",
    "torch_threads=1",
]


def overriding(base, *changes) -> list[str]:
    """`base` with `changes` applied, one override per key (Hydra takes a key only once)."""
    merged = {o.split("=", 1)[0]: o for o in base}
    merged.update({o.split("=", 1)[0]: o for o in changes})
    return list(merged.values())


def compose_cfg(overrides=()):
    register()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))


def _flat(tree, prefix=""):
    """Every tensor of a nested checkpoint dict, by path."""
    if isinstance(tree, torch.Tensor):
        return {prefix: tree}
    if isinstance(tree, dict):
        out = {}
        for k, v in tree.items():
            out.update(_flat(v, f"{prefix}/{k}"))
        return out
    return {}


def assert_same_checkpoint(a, b):
    """Two checkpoints hold the same tensors, bit for bit, and the same evaluations."""
    fa, fb = _flat(a), _flat(b)
    assert fa.keys() == fb.keys()
    for k in fa:
        assert torch.equal(fa[k], fb[k]), k

    def results(history):  # evaluations without their wall-clock
        return [{k: v for k, v in h.items() if "seconds" not in k} for h in history]

    assert results(a["history"]) == results(b["history"])


def as_from_a_shell() -> None:
    """A command typed in a shell starts with SIGINT at its default. A test run started in the
    background of a non-interactive shell (as CI may be) has SIGINT ignored, POSIX passes that on
    to its children, and Python keeps an inherited ignore: the sweep would never see the Ctrl-C."""
    signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    signal.signal(signal.SIGINT, signal.SIG_DFL)
