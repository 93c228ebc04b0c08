"""Composing configs exactly as `python train.py ...` does, and a tiny-run override set."""

from pathlib import Path

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


def compose_cfg(overrides=()):
    register()
    with initialize_config_dir(config_dir=str(CONF), version_base="1.3"):
        return compose(config_name="config", overrides=list(overrides))
