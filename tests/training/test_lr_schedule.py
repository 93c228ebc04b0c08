"""`optim.desired_kl`: after an update beyond twice the target KL the learning rate falls by 1.5,
below half of it climbs back up to `optim.lr`, and a resumed run continues the same schedule."""

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

from bfc.training import train
from bfc.training.lr_schedule import adapt_to_kl, set_learning_rate

from .helpers import TINY, compose_cfg


def _optimizer(lr=1e-3):
    return torch.optim.Adam([torch.nn.Parameter(torch.zeros(2))], lr=lr)


def test_the_rate_follows_the_kl_between_one_percent_and_the_base_rate():
    opt = _optimizer()
    rates = []
    for kl in [0.05, 0.05, 0.015, 0.001, 0.001, 0.001] + [1.0] * 20:
        set_learning_rate([opt], anneal=1.0)
        rates.append(opt.param_groups[0]["lr"])
        adapt_to_kl([opt], kl, desired_kl=0.01)
    expected = [1e-3, 1e-3 / 1.5, 1e-3 / 1.5**2, 1e-3 / 1.5**2, 1e-3 / 1.5, 1e-3, 1e-3]  # up to the base, no further
    assert rates[:7] == pytest.approx(expected)
    assert rates[-1] == pytest.approx(1e-5)  # never below 1% of the base
    set_learning_rate([opt], anneal=0.5)  # the anneal multiplies the KL's scale
    assert opt.param_groups[0]["lr"] == pytest.approx(0.5e-5)
    restored = _optimizer(lr=123.0)
    restored.load_state_dict(opt.state_dict())  # the schedule's state is the optimizer's
    set_learning_rate([restored], anneal=0.5)
    assert restored.param_groups[0]["lr"] == pytest.approx(0.5e-5)


def test_a_run_with_a_kl_target_slows_down_and_resumes_on_the_same_schedule(tmp_path):
    overrides = [
        *TINY,
        "collector.total_frames=3072",
        "jd.decay_frames=3072",
        "optim.anneal_lr=false",
        "optim.desired_kl=1e-9",  # every update goes beyond it
        "env.episode_seconds=0.2",
        "seed=5",
    ]
    full = tmp_path / "full"
    train(compose_cfg(overrides), full)
    ea = EventAccumulator(str(full / "tb"))
    ea.Reload()
    rates = [e.value for e in ea.Scalars("train/lr")]
    assert rates == pytest.approx([1e-3 / 1.5**k for k in range(6)])

    part = tmp_path / "part"
    train(compose_cfg([*overrides, "collector.total_frames=1024"]), part)  # "killed" after 2 batches
    train(compose_cfg([*overrides, f"resume={part}"]), part)
    a = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert a["optimizer"]["param_groups"][0]["kl_scale"] == b["optimizer"]["param_groups"][0]["kl_scale"]
    for name, weight in a["actor"].items():
        assert torch.equal(weight, b["actor"][name]), name


def test_bad_kl_targets_are_one_line():
    from bfc.config import validate

    for bad, allowed in (("0", "null or > 0"), ("-1", "null or > 0")):
        with pytest.raises(ValueError, match=f"optim.desired_kl must be {allowed}"):
            validate(compose_cfg([f"optim.desired_kl={bad}"]))
    with pytest.raises(ValueError, match="optim.desired_kl must be null with algo=trpo"):
        validate(compose_cfg(["algo=trpo", "optim.desired_kl=0.01"]))
