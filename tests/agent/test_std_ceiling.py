"""`model.max_std`: the Gaussian's std never exceeds the ceiling, in sampling, scoring and the
loss's gradient, and the ceiling travels with the policy (spec, file, config)."""

import math
import subprocess
import sys
from pathlib import Path

import pytest
import torch

from bfc.agent import PolicySpec, read_policy, save_policy
from bfc.config import compose


def test_the_std_is_capped_and_gets_no_gradient_above_the_ceiling():
    spec = PolicySpec(hidden=(8,), init_std=0.2, max_std=0.3)
    net = spec.make_net()
    with torch.no_grad():
        net.log_std.copy_(torch.log(torch.tensor([0.1, 0.2, 0.5, 2.0])))
    obs = torch.randn(64, spec.observation_size)
    loc, scale = net(obs)
    torch.testing.assert_close(scale[0], torch.tensor([0.1, 0.2, 0.3, 0.3]))
    torch.manual_seed(0)
    action, log_prob, _, sampled_scale = net.sample(obs)
    torch.testing.assert_close(sampled_scale, scale)
    torch.testing.assert_close(log_prob, torch.distributions.Normal(loc, scale).log_prob(action).sum(-1))
    # the spread of the samples is the capped std, not the parameter's
    assert (action - loc)[:, 3].std() < 0.5
    # a loss that would widen every std moves only those below the ceiling
    (-net.entropy(net(obs)[1]).sum()).backward()
    grad = net.log_std.grad
    assert (grad[:2] != 0).all() and (grad[2:] == 0).all()
    free = PolicySpec(hidden=(8,)).make_net()
    with torch.no_grad():
        free.log_std.fill_(math.log(2.0))
    assert torch.allclose(free(obs)[1], torch.full_like(loc, 2.0))


def test_the_ceiling_travels_with_the_policy_and_bad_values_are_one_line(tmp_path):
    spec = PolicySpec.from_config(compose(["model.max_std=0.25"]))
    assert spec.max_std == 0.25 and PolicySpec.from_config(compose([])).max_std is None
    save_policy(tmp_path / "p.pt", spec, spec.make_net())
    loaded = read_policy(tmp_path / "p.pt")
    assert loaded.spec.max_std == 0.25 and loaded.net().max_log_std == pytest.approx(math.log(0.25))
    for bad in (0.1, float("inf"), float("nan")):
        with pytest.raises(ValueError, match=r"model.max_std must be null or a number >= model.init_std"):
            PolicySpec(init_std=0.2, max_std=bad)
    result = subprocess.run(
        [sys.executable, "train.py", "model.max_std=0.1", f"hydra.run.dir={tmp_path}"],
        cwd=Path(__file__).resolve().parents[2],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert result.returncode == 2
    assert result.stderr.strip() == "error: model.max_std must be null or a number >= model.init_std (0.2), got 0.1"
