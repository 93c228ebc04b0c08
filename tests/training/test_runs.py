"""Tiny end-to-end runs of every ablation, resume, and a joblib multirun."""

import subprocess
import sys

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from bfc.config import ABLATIONS
from bfc.policy import load_policy
from bfc.training import train

from .helpers import ROOT, TINY, compose_cfg

REQUIRED_TAGS = {
    "train/episode_return",
    "train/episode_length",
    "train/jd_probability",
    "loss/objective",
    "loss/critic",
    "loss/entropy",
    "loss/approx_kl",
    "loss/clip_fraction",
    "eval/success_rate",
    "eval/position_error",
    "eval/attitude_error",
    "time/fps",
}


@pytest.mark.parametrize("name", ABLATIONS)
def test_tiny_run_of_every_variant(name, tmp_path):
    cfg = compose_cfg([f"+ablation={name}", *TINY, "env.episode_seconds=0.2"])
    summary = train(cfg, tmp_path)
    assert summary["frames"] == 2048
    ea = EventAccumulator(str(tmp_path / "tb"))
    ea.Reload()
    assert REQUIRED_TAGS <= set(ea.Tags()["scalars"])
    if cfg.css.enabled:
        assert "css/square_values" in ea.Tags()["images"]
    actor, payload = load_policy(tmp_path / "policy.pt")
    assert payload["env"]["control_hz"] == cfg.env.control_hz
    obs = torch.zeros(3, payload["observation"]["size"])
    from tensordict import TensorDict

    out = actor(TensorDict({"observation": obs}, batch_size=[3]))
    assert out["action"].shape == (3, 4)
    # a checkpoint is data, never code
    torch.load(tmp_path / "checkpoints" / "last.pt", weights_only=True)


def test_resumed_run_ends_like_an_uninterrupted_one(tmp_path):
    overrides = [*TINY, "collector.total_frames=4096", "env.episode_seconds=0.2", "seed=3"]
    full = tmp_path / "full"
    train(compose_cfg(overrides), full)

    part = tmp_path / "part"
    train(compose_cfg([*overrides, "collector.total_frames=2048"]), part)  # "killed" after 2 batches
    resumed = train(compose_cfg([*overrides, f"resume={part}"]), part)

    a = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert resumed["frames"] == a["frames"] == b["frames"] == 4096
    ta, tb = a["env"]["transforms"], b["env"]["transforms"]
    jd_frames = [k for k in ta if k.endswith(".frames")]
    assert jd_frames and all(torch.equal(ta[k], tb[k]) for k in jd_frames)
    css_values = [k for k in ta if k.endswith(".values")]
    assert css_values and all(torch.equal(ta[k], tb[k]) for k in css_values)
    for k in ta:
        assert torch.equal(ta[k], tb[k]), k
    for k in a["actor"]:
        assert torch.equal(a["actor"][k], b["actor"][k]), k
    # resuming a finished run collects nothing more
    again = train(compose_cfg([*overrides, f"resume={part}"]), part)
    assert again["frames"] == 4096
    assert torch.load(part / "checkpoints" / "last.pt", weights_only=True)["frames"] == 4096


def test_joblib_multirun_makes_two_run_directories(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    r = subprocess.run(
        [
            sys.executable,
            "train.py",
            "-m",
            "hydra/launcher=joblib",
            "hydra.launcher.n_jobs=1",
            "+ablation=jd,jd_css_tdts",
            *TINY,
            "env.episode_seconds=0.2",
            f"hydra.sweep.dir={tmp_path}",
        ],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    runs = sorted(p.parent for p in tmp_path.glob("*/*/policy.pt"))
    assert len(runs) == 2, list(tmp_path.iterdir())
    assert {p.parent.name for p in runs} == {"jd", "jd_css_tdts"}


def test_tiny_run_with_the_adaptive_kl_loss(tmp_path):
    cfg = compose_cfg([*TINY, "loss.kind=kl", "env.episode_seconds=0.2"])
    summary = train(cfg, tmp_path)
    assert summary["frames"] == 2048
    ea = EventAccumulator(str(tmp_path / "tb"))
    ea.Reload()
    assert "loss/kl_beta" in ea.Tags()["scalars"]
    betas = [e.value for e in ea.Scalars("loss/kl_beta")]
    assert all(b > 0 for b in betas)
