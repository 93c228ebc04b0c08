"""Tiny end-to-end runs of every ablation, resume, and a joblib multirun."""

import subprocess
import sys

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from bfc.agent import load_policy, read_policy
from bfc.config import ABLATIONS
from bfc.training import train

from .helpers import ROOT, TINY, assert_same_checkpoint, compose_cfg

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
    "eval/crash_rate",  # eval/hover_error and eval/attitude_error come with the first successful flight
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
    if cfg.tdts.enabled:
        assert "train/tdts_fired" in ea.Tags()["scalars"]
    spec, net = load_policy(tmp_path / "policy.pt")
    assert spec.control_hz == cfg.env.control_hz and spec.observation_size == 22  # no integral in the paper variants
    assert net.mean(torch.zeros(3, spec.observation_size)).shape == (3, 4)
    assert read_policy(tmp_path / "policy.pt").info["frames"] > 0
    # a checkpoint is data, never code
    torch.load(tmp_path / "checkpoints" / "last.pt", weights_only=True)


def _env_state(ckpt: dict) -> dict:
    collection = ckpt["collector"]
    collection = collection["workers"][0]["collection"] if "workers" in collection else collection
    return collection["collector"]["env_state_dict"]


@pytest.mark.parametrize(
    "collector",
    [
        ["collector.kind=torchrl"],
        ["collector.kind=fused"],
        ["collector.kind=fused", "collector.workers=1"],
        ["collector.kind=fused", "collector.workers=2"],
    ],
)
def test_resumed_run_ends_like_an_uninterrupted_one(tmp_path, collector):
    # JD's schedule and the learning-rate anneal follow collector.total_frames: pin them, since the
    # "killed" run is a shorter one
    overrides = [
        *collector,
        *TINY,
        "collector.total_frames=4096",
        "jd.decay_frames=4096",
        "optim.anneal_lr=false",
        "env.episode_seconds=0.2",
        "seed=3",
    ]
    full = tmp_path / "full"
    train(compose_cfg(overrides), full)

    part = tmp_path / "part"
    train(compose_cfg([*overrides, "collector.total_frames=2048"]), part)  # "killed" after 2 batches
    resumed = train(compose_cfg([*overrides, f"resume={part}"]), part)

    a = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert resumed["frames"] == a["frames"] == b["frames"] == 4096
    env_state = _env_state(a)
    # the checkpoint holds the base env's state (physics, motors, generator) beside the transforms'
    assert {"physics", "motor", "goal", "generator"} <= set(env_state["base_env._extra_state"])
    assert any(k.endswith(".frames") for k in env_state) and any(k.endswith(".values") for k in env_state)
    assert_same_checkpoint(a, b)  # bit-identical: env, transforms, carrier, models, optimizer, RNG
    # resuming a finished run collects nothing more
    again = train(compose_cfg([*overrides, f"resume={part}"]), part)
    assert again["frames"] == 4096
    assert torch.load(part / "checkpoints" / "last.pt", weights_only=True)["frames"] == 4096


def test_a_corrupted_last_checkpoint_falls_back_one_step(tmp_path, capsys):
    overrides = [
        *TINY,
        "collector.total_frames=3072",
        "jd.decay_frames=3072",
        "optim.anneal_lr=false",  # the anneal follows total_frames, which the "killed" run shortens
        "env.episode_seconds=0.2",
        "seed=4",
    ]
    full = tmp_path / "full"
    train(compose_cfg(overrides), full)

    part = tmp_path / "part"
    train(compose_cfg([*overrides, "collector.total_frames=2048"]), part)  # checkpoints at 1024 and 2048
    assert torch.load(part / "checkpoints" / "previous.pt", weights_only=True)["frames"] == 1024
    (part / "checkpoints" / "last.pt").write_bytes(b"half a checkpoint")  # killed while the disk filled
    (part / "summary.json").unlink()
    train(compose_cfg([*overrides, f"resume={part}"]), part)
    err = capsys.readouterr().err
    assert "last.pt is unreadable" in err and "resuming from" in err and "previous.pt" in err
    # from 1024 frames on, the resumed run is the uninterrupted one
    a = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert a["frames"] == b["frames"] == 3072
    assert_same_checkpoint(a, b)


def test_resume_with_no_readable_checkpoint_is_a_clear_error(tmp_path):
    run = tmp_path / "run"
    train(compose_cfg([*TINY, "collector.total_frames=1024", "env.episode_seconds=0.2"]), run)
    for name in ("last.pt", "previous.pt"):
        (run / "checkpoints" / name).write_bytes(b"garbage")
    r = subprocess.run(
        [sys.executable, "train.py", f"resume={run}", "hydra.run.dir=/tmp/bfc-test-cli"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 2, r.stderr[-2000:]
    assert "cannot resume" in r.stderr and "unreadable" in r.stderr and "Traceback" not in r.stderr


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


def test_the_mirror_loss_runs_from_mirror_from_frames(tmp_path):
    overrides = ["env/airframe=x500", "loss.mirror_coeff=1", "loss.mirror_from_frames=1024", "env.episode_seconds=0.2"]
    train(compose_cfg([*TINY, *overrides]), tmp_path)
    ea = EventAccumulator(str(tmp_path / "tb"))
    ea.Reload()
    batches = [e.step for e in ea.Scalars("loss/objective")]
    mirrored = [e.step for e in ea.Scalars("loss/mirror")]
    assert batches == [512, 1024, 1536, 2048] and mirrored == [1536, 2048]  # the batches after 1024 frames


def test_stop_at_success_ends_the_run_after_patience_evaluations(tmp_path):
    # success >= 0 holds at every evaluation: the run stops after the 2nd one
    overrides = [*TINY, "collector.total_frames=8192", "collector.stop_at_success=0.0", "collector.stop_patience=2"]
    summary = train(compose_cfg([*overrides, "env.episode_seconds=0.2"]), tmp_path)
    assert summary["stopped_early"] and summary["frames"] == 2048
    assert [h["frames"] for h in summary["history"]] == [1024, 2048]
    assert (tmp_path / "policy_last.pt").is_file()
    assert torch.load(tmp_path / "checkpoints" / "last.pt", weights_only=True)["frames"] == 2048


def test_early_evaluations_come_every_early_interval_then_every_interval(tmp_path):
    from types import SimpleNamespace

    from bfc.training.runner import next_evaluation

    e = SimpleNamespace(interval_frames=1000, early_frames=500, early_interval_frames=200)
    schedule, frames = [], 0
    while frames < 3000:
        frames = next_evaluation(frames, e)
        schedule.append(frames)
    assert schedule == [200, 400, 600, 1000, 2000, 3000]
    assert next_evaluation(0, SimpleNamespace(interval_frames=1000, early_frames=0, early_interval_frames=200)) == 1000
    overrides = [*TINY, "eval.interval_frames=1024", "eval.early_frames=1024", "eval.early_interval_frames=512"]
    summary = train(compose_cfg([*overrides, "eval.at_start=true"]), tmp_path / "early")
    assert [h["frames"] for h in summary["history"]] == [0, 512, 1024, 2048]
    # by default the untrained policy is not flown; evaluating more often (or at frame 0) does not
    # change what is learned
    plain = train(compose_cfg([*TINY, "eval.early_frames=0"]), tmp_path / "plain")
    assert [h["frames"] for h in plain["history"]] == [1024, 2048]
    early, plain = (load_policy(tmp_path / run / "policy_last.pt")[1] for run in ("early", "plain"))
    for a, b in zip(early.parameters(), plain.parameters(), strict=True):
        assert torch.equal(a, b)


def test_evaluating_in_the_background_is_evaluating_in_place(tmp_path):
    """eval.background: the same evaluations (in the same order), checkpoints and policy files as
    flying them in the learner, whatever the two processes' timing."""
    overrides = [*TINY, "collector.total_frames=4096", "eval.at_start=true", "collector.workers=1"]
    for background in (True, False):
        train(compose_cfg([*overrides, f"eval.background={background}"]), tmp_path / str(background))
    a, b = (torch.load(tmp_path / run / "checkpoints" / "last.pt", weights_only=True) for run in ("True", "False"))
    assert [h["frames"] for h in a["history"]] == [0, 1024, 2048, 3072, 4096]
    assert_same_checkpoint(a, b)
    for policy in ("policy.pt", "policy_last.pt"):
        (sa, na), (sb, nb) = (load_policy(tmp_path / run / policy) for run in ("True", "False"))
        assert sa == sb
        for x, y in zip(na.state_dict().values(), nb.state_dict().values(), strict=True):
            assert torch.equal(x, y), policy
