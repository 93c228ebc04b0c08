"""JD and CSS start samplers, and TDTS."""

import math

import pytest
import torch
from tensordict import TensorDict

from bfc import keys
from bfc.envs.rotations import quat_to_matrix
from bfc.factory import find_transform, make_env
from bfc.transforms import ControlledStartingState, JumpingDistribution, TimeDependentTerminalState


def only(cfg, n=512, **enabled):
    cfg.env.num_envs = n
    for name in ("jd", "css", "tdts"):
        cfg[name].enabled = enabled.get(name, False)
    return cfg


def air_fraction(env):
    z = env.reset()[keys.POSITION][:, 2]
    return (z > env.base_env.ground_height + 0.01).float().mean().item()


def test_jd_air_fraction_follows_p_of_t(cfg):
    cfg = only(cfg, jd=True)
    cfg.jd.p0, cfg.jd.decay_frames = 1.0, 1000
    env = make_env(cfg, seed=0)
    jd = find_transform(env, JumpingDistribution)
    assert jd.probability == 1.0 and air_fraction(env) == 1.0
    jd.frames.fill_(500)
    assert jd.probability == pytest.approx(0.5)
    assert air_fraction(env) == pytest.approx(0.5, abs=4 * math.sqrt(0.25 / 512))
    jd.frames.fill_(1000)
    assert jd.probability == 0.0 and air_fraction(env) == 0.0
    jd.frames.fill_(10**9)
    assert air_fraction(env) == 0.0


def test_jd_counts_frames_and_restores_from_state_dict(cfg):
    cfg = only(cfg, n=8, jd=True)
    env = make_env(cfg, seed=0)
    env.rollout(10, break_when_any_done=False)
    jd = find_transform(env, JumpingDistribution)
    assert int(jd.frames) == 80
    other = find_transform(make_env(cfg, seed=1), JumpingDistribution)
    other.load_state_dict(jd.state_dict())
    assert int(other.frames) == 80 and other.probability == jd.probability


def test_jd_air_starts_respect_ranges(cfg):
    cfg = only(cfg, jd=True)
    cfg.jd.z_range, cfg.jd.roll_range, cfg.jd.velocity_range = [1.0, 2.0], [-30.0, 30.0], [-1.0, 1.0]
    td = make_env(cfg, seed=0).reset()
    z, roll = td[keys.POSITION][:, 2], td[keys.ODOMETRY][:, 9]
    assert z.min() >= 1.0 and z.max() <= 2.0
    assert roll.abs().max() <= math.radians(30) + 1e-5 and roll.abs().max() > math.radians(25)
    v = td[keys.LINEAR_VELOCITY]
    assert v.abs().max() <= 1.0 and v.std() > 0.3


def test_jd_inverted_share_mirrors_that_share_upside_down(cfg):
    cfg = only(cfg, n=2000, jd=True)
    cfg.jd.roll_range, cfg.jd.pitch_range = [-60.0, 60.0], [-60.0, 60.0]  # every drawn start upright

    def upside_down(share, scale=1.0):
        cfg.jd.inverted_share = share
        env = make_env(cfg, seed=0)
        find_transform(env, JumpingDistribution).inverted_scale = scale
        return quat_to_matrix(env.reset()[keys.QUATERNION])[:, 2, 2]  # the body z axis's vertical component

    assert (upside_down(0.0) > 0).all()
    up = upside_down(0.4)
    inverted = up < 0
    assert inverted.float().mean().item() == pytest.approx(0.4, abs=4 * math.sqrt(0.24 / 2000))
    assert up[inverted].max() <= -0.25 + 1e-5  # drawn cos(roll) cos(pitch) >= 0.25, mirrored to <= -0.25
    assert up[inverted].min() >= -1.0 - 1e-5 and up[inverted].min() < -0.99
    half = (upside_down(0.4, scale=0.5) < 0).float().mean().item()  # the curriculum's progress scales it
    assert half == pytest.approx(0.2, abs=4 * math.sqrt(0.16 / 2000))
    with pytest.raises(ValueError, match="jd.inverted_share"):
        JumpingDistribution(2, inverted_share=1.5)


def test_jd_inverted_at_rest_releases_that_share_of_upside_down_starts_still(cfg):
    cfg = only(cfg, n=2000, jd=True)
    cfg.jd.roll_range, cfg.jd.pitch_range = [-60.0, 60.0], [-60.0, 60.0]
    cfg.jd.velocity_range, cfg.jd.angular_velocity_range = [-1.0, 1.0], [-100.0, 100.0]
    cfg.jd.inverted_share, cfg.jd.inverted_at_rest = 0.5, 0.4
    td = make_env(cfg, seed=0).reset()
    inverted = quat_to_matrix(td[keys.QUATERNION])[:, 2, 2] < 0
    moving = torch.cat((td[keys.LINEAR_VELOCITY], td[keys.ANGULAR_VELOCITY]), -1).abs().amax(-1)
    still = moving == 0
    assert not still[~inverted].any()  # right-way-up starts keep their drawn velocities
    n = int(inverted.sum())
    assert still[inverted].float().mean().item() == pytest.approx(0.4, abs=4 * math.sqrt(0.24 / n))
    assert moving[inverted & ~still].min() > 0
    with pytest.raises(ValueError, match="jd.inverted_at_rest"):
        JumpingDistribution(2, inverted_share=0.5, inverted_at_rest=-0.1)


def test_jd_inverted_spread_turns_upside_down_starts_nearer_180_deg(cfg):
    cfg = only(cfg, n=2000, jd=True)
    cfg.jd.roll_range, cfg.jd.pitch_range = [-60.0, 60.0], [-60.0, 60.0]  # every drawn start upright
    cfg.jd.inverted_share = 0.5

    def body_z(spread, scale=1.0):
        cfg.jd.inverted_spread = spread
        env = make_env(cfg, seed=0)
        find_transform(env, JumpingDistribution).inverted_scale = scale
        return quat_to_matrix(env.reset()[keys.QUATERNION])[:, 2, 2]

    wide, near = body_z(1.0), body_z(0.5)
    assert torch.equal(wide < 0, near < 0)  # the same starts are turned over: no extra random draw
    assert torch.equal(wide[wide > 0], near[near > 0])  # and the right-way-up ones are untouched
    # roll and pitch within +-30 deg of upside down: cos(roll) cos(pitch) <= -cos(30 deg)^2
    assert near[near < 0].max() <= -0.75 + 1e-5 < wide[wide < 0].max()
    assert (near[near < 0] < -0.9).float().mean() > (wide[wide < 0] < -0.9).float().mean() + 0.2
    # halfway through the curriculum, halfway there: within +-45 deg, cos(45 deg)^2 = 0.5
    half = body_z(0.5, scale=0.5)
    assert -0.75 < half[half < 0].max() <= -0.5 + 1e-5
    for bad in (0.0, 1.5):
        with pytest.raises(ValueError, match="jd.inverted_spread"):
            JumpingDistribution(2, inverted_share=0.5, inverted_spread=bad)


def test_jd_schedule_and_bad_values():
    jd = JumpingDistribution(2, p0=0.8, decay_frames=100, schedule="cosine")
    assert jd.probability_at(0) == pytest.approx(0.8) and jd.probability_at(50) == pytest.approx(0.4)
    assert jd.probability_at(100) == 0.0
    with pytest.raises(ValueError, match="jd.decay_frames"):
        JumpingDistribution(2, decay_frames=-1)
    with pytest.raises(ValueError, match="jd.p0"):
        JumpingDistribution(2, p0=1.5)
    with pytest.raises(ValueError, match="jd.schedule"):
        JumpingDistribution(2, schedule="step")


def test_css_sv_follows_eq_18_exactly():
    css = ControlledStartingState(4, grid=2)
    sq = torch.tensor([3])
    css.update(sq, torch.tensor([1.0]))  # first visit initialises
    assert css.values[3].item() == 1.0
    css.update(sq, torch.tensor([0.5]))
    assert css.values[3].item() == pytest.approx(0.75)
    css.update(sq, torch.tensor([-1.0]))
    assert css.values[3].item() == pytest.approx(-0.125)
    assert not css.visited[:3].any()
    assert css.value_grid.shape == (2, 2) and torch.isnan(css.value_grid[0]).all()


def test_css_draws_the_worst_square_markedly_more_often(cfg):
    cfg = only(cfg, n=4096, css=True)
    env = make_env(cfg, seed=0)
    css = find_transform(env, ControlledStartingState)
    n_sq = css.grid * css.grid
    rewards = torch.full((n_sq,), 1.0)
    rewards[5] = -1.0
    css.update(torch.arange(n_sq), rewards)
    pos = env.reset()[keys.POSITION]
    side = 2 * css.xy_range / css.grid
    ix = ((pos[:, 0] + css.xy_range) / side).floor().long()
    iy = ((pos[:, 1] + css.xy_range) / side).floor().long()
    share = ((iy * css.grid + ix) == 5).float().mean().item()
    assert share > 4 / n_sq  # uniform would be 1/16
    assert css.probabilities().min() >= css.uniform / n_sq  # no square starves
    torch.testing.assert_close(pos[:, 2], torch.full((4096,), env.base_env.ground_height))  # D's ground start


def test_css_composes_with_jd(cfg):
    cfg = only(cfg, n=256, jd=True, css=True)
    env = make_env(cfg, seed=0)
    css = find_transform(env, ControlledStartingState)
    css.update(torch.arange(16), torch.where(torch.arange(16) == 0, -1.0, 1.0))
    pos = env.reset()[keys.POSITION]
    assert (pos[:, 2] >= 0.5).all()  # JD (p = 1): in the air
    in_square0 = (pos[:, 0] < -1.0) & (pos[:, 1] < -1.0)  # CSS: square 0 is [-2, -1]^2
    assert in_square0.float().mean() > 0.3


def test_css_updates_from_real_episodes(cfg):
    cfg = only(cfg, n=16, css=True)
    cfg.env.control_hz, cfg.env.episode_seconds = 250.0, 0.04  # 10 steps
    env = make_env(cfg, seed=0)
    assert env.base_env.max_episode_steps == 10
    env.rollout(25, break_when_any_done=False)
    css = find_transform(env, ControlledStartingState)
    assert int(css.episodes.sum()) == 32  # two full episodes per env ended


def _tdts_step(tdts, pos, goal=(0.0, 0.0, 1.5)):
    n = pos.shape[0]
    nxt = TensorDict(
        {
            keys.STATE: {"position": pos},
            keys.GOAL: torch.tensor(goal).expand(n, 3),
            keys.DONE: torch.zeros(n, 1, dtype=torch.bool),
            keys.TERMINATED: torch.zeros(n, 1, dtype=torch.bool),
            keys.TRUNCATED: torch.zeros(n, 1, dtype=torch.bool),
        },
        batch_size=[n],
    )
    return tdts._step(None, nxt)


def test_tdts_fires_exactly_after_threshold_and_only_for_those_envs():
    tdts = TimeDependentTerminalState(3, zeta=0.1, threshold_seconds=0.2, dt=0.004)  # 50 steps
    inside = torch.tensor([[0.05, -0.05, 1.55], [0.0, 0.0, 1.5], [0.5, 0.0, 1.5]])
    for t in range(1, 51):
        out = _tdts_step(tdts, inside)
        fired = out[keys.TRUNCATED].squeeze(-1)
        assert fired.tolist() == ([True, True, False] if t == 50 else [False, False, False]), t
        assert torch.equal(out[keys.DONE], out[keys.TRUNCATED]) and not out[keys.TERMINATED].any()


def test_tdts_timer_restarts_when_leaving_the_box():
    tdts = TimeDependentTerminalState(1, zeta=0.1, threshold_seconds=0.2, dt=0.004, as_terminal=True)
    inside, outside = torch.tensor([[0.0, 0.0, 1.5]]), torch.tensor([[0.0, 0.11, 1.5]])
    for _ in range(49):
        assert not _tdts_step(tdts, inside)[keys.DONE].any()
    assert not _tdts_step(tdts, outside)[keys.DONE].any()  # one axis out: the count restarts
    for _ in range(49):
        assert not _tdts_step(tdts, inside)[keys.DONE].any()
    out = _tdts_step(tdts, inside)
    assert out[keys.TERMINATED].all() and out[keys.DONE].all()


def test_tdts_bad_values_name_the_key():
    with pytest.raises(ValueError, match="tdts.zeta"):
        TimeDependentTerminalState(1, zeta=0.0)
    with pytest.raises(ValueError, match="css.grid"):
        ControlledStartingState(1, grid=0)
