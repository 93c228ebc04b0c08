"""Latency transforms: an observation k steps old (the reset's in the first steps), a command
applied k steps late (hover before), per-env random delays, and their queues in the state_dict."""

import copy

import pytest
import torch

from bfc import keys
from bfc.factory import make_env
from bfc.transforms import ActionDelay, ObservationDelay


def rollout(cfg, latency, steps=12, n=8, seed=3, actions=None):
    """Odometry seen, ground-truth motor speeds and the env's applied commands over `steps`."""
    cfg.env.num_envs = n
    for c in (cfg.jd, cfg.css, cfg.tdts):
        c.enabled = False
    env = make_env(cfg, seed=seed, latency=latency)
    td = env.reset()
    seen, truth = [td.get(keys.ODOMETRY).clone()], [td.select(keys.STATE).clone()]
    g = torch.Generator().manual_seed(0)
    for t in range(steps):
        a = actions[t] if actions is not None else 0.3 * (2 * torch.rand(n, 4, generator=g) - 1)
        td = env.step(td.set(keys.ACTION, a))["next"].clone()
        seen.append(td.get(keys.ODOMETRY).clone())
        truth.append(td.select(keys.STATE).clone())
    return torch.stack(seen, 0), torch.stack(truth, 0), env


@pytest.mark.parametrize("k", [1, 3])
def test_the_odometry_seen_is_k_steps_old_and_the_resets_in_the_first_steps(cfg, k):
    clean, _, _ = rollout(cfg, {})
    late, _, _ = rollout(cfg, {"observation_steps": k})
    for t in range(len(clean)):
        torch.testing.assert_close(late[t], clean[max(0, t - k)], rtol=0, atol=0)


def test_a_late_command_moves_the_motors_k_steps_later_and_hover_is_held_before(cfg):
    actions = [0.4 * torch.ones(8, 4) * (1 if t % 3 else -1) for t in range(12)]
    _, now, _ = rollout(cfg, {}, actions=actions)
    _, late, env = rollout(cfg, {"action_steps": 2}, actions=actions)
    # the physics is deterministic: the delayed run equals the undelayed run fed hover twice first
    hover = torch.zeros(8, 4)
    _, fed, _ = rollout(cfg, {}, actions=[hover, hover, *actions[:10]])
    torch.testing.assert_close(late[keys.MOTOR_SPEEDS], fed[keys.MOTOR_SPEEDS], rtol=0, atol=0)
    assert not torch.equal(late[keys.MOTOR_SPEEDS], now[keys.MOTOR_SPEEDS])


def test_random_delays_are_drawn_per_env_at_each_reset_and_resume_exactly(cfg):
    cfg.env.num_envs = 64
    for c in (cfg.jd, cfg.css, cfg.tdts):
        c.enabled = False
    env = make_env(cfg, seed=3, latency={"observation_steps": [0, 4], "action_steps": [0, 2]})
    td = env.reset()
    delays = [t.delay for t in env.transform if isinstance(t, (ObservationDelay, ActionDelay))]
    assert set(delays[0].tolist()) == {0, 1, 2, 3, 4} and set(delays[1].tolist()) == {0, 1, 2}
    g = torch.Generator().manual_seed(1)
    actions = [0.3 * (2 * torch.rand(64, 4, generator=g) - 1) for _ in range(6)]
    for a in actions[:3]:
        td = env.step(td.set(keys.ACTION, a))["next"].clone()
    state, carried = copy.deepcopy(env.state_dict()), td.clone()  # state_dict holds the live buffers
    assert any(str(k).endswith("queue") for k in state)
    ahead = []
    for a in actions[3:]:
        td = env.step(td.set(keys.ACTION, a))["next"].clone()
        ahead.append(td.get(keys.ODOMETRY))
    other = make_env(cfg, seed=99, latency={"observation_steps": [0, 4], "action_steps": [0, 2]})
    other.reset()
    other.load_state_dict(state)
    td = carried
    for a, expected in zip(actions[3:], ahead, strict=True):
        td = other.step(td.set(keys.ACTION, a))["next"].clone()
        assert torch.equal(td.get(keys.ODOMETRY), expected)


def test_bad_delays_are_one_line():
    with pytest.raises(ValueError, match="latency.observation_steps"):
        ObservationDelay(4, -1)
    with pytest.raises(ValueError, match="latency.observation_steps"):
        ObservationDelay(4, [3, 1])
    with pytest.raises(ValueError, match="latency.action_steps"):
        ActionDelay(4, 1.5, initial=450.0)


@pytest.mark.parametrize(
    "overrides, line",
    [
        (["noise.bias=-0.1"], "noise.bias must be a number >= 0 or 18 of them, got -0.1"),
        (["noise.bias=0.1"], "noise.bias must be 0 with noise.kind=none"),
        (["noise.kind=gaussian", "noise.bias=[1,2]"], "noise.bias must be a number >= 0 or 18 of them"),
    ],
)
def test_a_bad_bias_is_one_line_before_anything_runs(overrides, line):
    from bfc.config import compose, validate

    with pytest.raises(ValueError) as err:
        validate(compose(overrides))
    assert str(err.value).startswith(line) and "\n" not in str(err.value)


def test_a_bad_latency_stops_train_py_with_one_line(tmp_path):
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    r = subprocess.run(
        [sys.executable, "train.py", "latency.observation_steps=-1", f"hydra.run.dir={tmp_path}"],
        cwd=root,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [
        "error: latency.observation_steps must be a whole number of control steps >= 0, "
        "or a [low, high] range of them, got -1"
    ]
