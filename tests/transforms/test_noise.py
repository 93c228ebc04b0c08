"""Odometry noise: statistics, element masks, ground truth untouched, OU theory, restart on reset."""

import math

import pytest
import torch
from tensordict import TensorDict

from bfc import keys
from bfc.factory import make_env
from bfc.transforms import OUOdometryNoise, element_mask


def twin_rollouts(cfg, noise, steps=30, n=256):
    """The same flights with and without noise (fixed actions, same seed)."""
    cfg.env.num_envs = n
    for c in (cfg.jd, cfg.css, cfg.tdts):
        c.enabled = False
    out = []
    for nz in ({"kind": "none"}, noise):
        env = make_env(cfg, noise=nz, seed=3)
        td = env.reset()
        rows = []
        for _ in range(steps):
            td = env.step(td.set(keys.ACTION, torch.full((n, 4), 0.05)))["next"].clone()
            rows.append(td.select(keys.ODOMETRY, keys.STATE).clone())
        out.append(torch.stack(rows, 1))
    return out


def test_gaussian_noise_statistics_per_element(cfg):
    std = torch.linspace(0.01, 0.2, 18)
    clean, noisy = twin_rollouts(cfg, {"kind": "gaussian", "std": std.tolist(), "elements": "all"})
    diff = (noisy[keys.ODOMETRY] - clean[keys.ODOMETRY]).reshape(-1, 18)
    n = diff.shape[0]
    assert diff.mean(0).abs().max() < 5 * std.max() / math.sqrt(n)
    torch.testing.assert_close(diff.std(0), std, rtol=0.05, atol=0)
    # ground truth is never touched
    assert torch.equal(noisy[keys.POSITION], clean[keys.POSITION])
    assert torch.equal(noisy[keys.QUATERNION], clean[keys.QUATERNION])


def test_noise_on_position_only_leaves_other_elements_bit_identical(cfg):
    clean, noisy = twin_rollouts(cfg, {"kind": "gaussian", "std": 0.1, "elements": "position"}, steps=5, n=64)
    diff = noisy[keys.ODOMETRY] - clean[keys.ODOMETRY]
    assert (diff[..., 0:3].abs() > 0).float().mean() > 0.99
    assert torch.equal(noisy[keys.ODOMETRY][..., 3:], clean[keys.ODOMETRY][..., 3:])


def test_explicit_element_list():
    assert element_mask([0, 5, 17]).nonzero().flatten().tolist() == [0, 5, 17]
    with pytest.raises(ValueError, match="noise.elements"):
        element_mask("velocity")
    with pytest.raises(ValueError, match="noise.elements"):
        element_mask([18])


def test_negative_std_is_rejected():
    with pytest.raises(ValueError, match="noise.std"):
        OUOdometryNoise(4, std=-0.1)


def _ou_series(noise, steps):
    n = noise.num_envs
    out = []
    for _ in range(steps):
        td = TensorDict({keys.ODOMETRY: torch.zeros(n, 18)}, batch_size=[n])
        out.append(noise._step(td, td)[keys.ODOMETRY][:, 0].clone())
    return torch.stack(out, 1)


def test_ou_stationary_std_and_lag1_autocorrelation_match_theory():
    theta, dt, std = 10.0, 0.01, 0.05
    noise = OUOdometryNoise(2048, std=std, theta=theta, dt=dt)
    noise.set_seed(0)
    x = _ou_series(noise, 400)[:, 100:]  # after 1 s = 10 time constants of burn-in
    assert x.std().item() == pytest.approx(std, rel=0.03)
    a, b = x[:, :-1].flatten(), x[:, 1:].flatten()
    rho = ((a * b).mean() / (a * a).mean()).item()
    assert rho == pytest.approx(math.exp(-theta * dt), abs=0.01)


def test_ou_restarts_at_reset_only_for_reset_envs():
    noise = OUOdometryNoise(4, std=0.1, theta=1.0, dt=0.004)
    _ou_series(noise, 50)
    before = noise.x.clone()
    mask = torch.tensor([True, False, True, False])
    reset_td = TensorDict({keys.RESET: mask.unsqueeze(-1)}, batch_size=[4])
    out = noise._reset(reset_td, TensorDict({keys.ODOMETRY: torch.zeros(4, 18)}, batch_size=[4]))
    assert (out[keys.ODOMETRY][[0, 2]] == 0).all()
    assert torch.equal(out[keys.ODOMETRY][[1, 3]], before[[1, 3]])
