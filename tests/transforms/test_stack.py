"""The full transform stack on the env: specs, partial resets, seeding, policy observation."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from bfc import keys
from bfc.factory import find_transform, make_env
from bfc.transforms import GivenStarts, PolicyObservation


def full_stack(cfg, n=6):
    cfg.env.num_envs = n
    cfg.noise.kind = "ou"
    return make_env(cfg, seed=0, given_starts=True)


def test_full_stack_passes_check_env_specs(cfg):
    env = full_stack(cfg)
    check_env_specs(env)
    assert env.action_spec.space.low.min() == -1 and env.action_spec.space.high.max() == 1


def test_every_transform_combination_passes_check_env_specs(cfg):
    cfg.env.num_envs = 3
    for jd in (False, True):
        for css in (False, True):
            for tdts in (False, True):
                cfg.jd.enabled, cfg.css.enabled, cfg.tdts.enabled = jd, css, tdts
                cfg.noise.kind = "gaussian" if jd else "none"
                check_env_specs(make_env(cfg, seed=0))


def test_partial_reset_keeps_other_envs_state(cfg):
    env = full_stack(cfg, n=4)
    td = env.reset()
    for _ in range(10):
        td = env.step(td.set(keys.ACTION, torch.zeros(4, 4)))["next"].clone()
    mask = torch.tensor([False, True, False, False]).unsqueeze(-1)
    after = env.reset(td.clone().set("_reset", mask))
    keep = [0, 2, 3]
    assert torch.equal(after[keys.POSITION][keep], td[keys.POSITION][keep])
    assert torch.equal(after[keys.MOTOR_SPEEDS][keep], td[keys.MOTOR_SPEEDS][keep])
    assert not torch.equal(after[keys.POSITION][1], td[keys.POSITION][1])


def test_seeded_stacks_reproduce(cfg):
    def run():
        env = full_stack(cfg.copy(), n=8)
        torch.manual_seed(0)
        return env.rollout(60, break_when_any_done=False)

    a, b = run(), run()
    assert torch.equal(a["next", keys.ODOMETRY], b["next", keys.ODOMETRY])


def test_policy_observation_is_goal_relative(cfg):
    cfg.env.num_envs = 2
    env = make_env(cfg, samplers=False, given_starts=True, seed=0)
    obs = find_transform(env, PolicyObservation)
    start = torch.zeros(2, 12)
    start[:, 0:3] = torch.tensor([1.0, -1.0, 2.0])
    env.transform[0].set_starts(start)
    td = env.reset()
    torch.testing.assert_close(td[keys.OBSERVATION][:, 0:3], torch.tensor([[1.0, -1.0, 0.5]] * 2))
    torch.testing.assert_close(td[keys.OBSERVATION][:, 3:12], torch.eye(3).flatten().expand(2, 9))
    assert td[keys.OBSERVATION].shape[-1] == obs.size


def test_observation_carries_the_previous_command_relative_to_hover(cfg):
    cfg.env.num_envs = 2
    env = make_env(cfg, samplers=False, seed=0)
    td = env.reset()
    assert (td[keys.OBSERVATION][:, -4:] == 0).all()
    action = torch.tensor([[0.1, -0.2, 0.3, 0.0], [0.5, 0.5, -0.5, -0.5]])
    nxt = env.step(td.set(keys.ACTION, action))["next"]
    torch.testing.assert_close(nxt[keys.OBSERVATION][:, -4:], action)


def test_reward_is_positive_everywhere_short_of_a_crash(cfg):
    cfg.env.num_envs = 64
    cfg.tdts.enabled = False
    env = make_env(cfg, seed=1)
    td = env.rollout(200, break_when_any_done=False)
    r = td["next", "reward"].squeeze(-1)
    crashed = td["next", keys.TERMINATED].squeeze(-1)
    assert (r[~crashed] > 0).all() and (r[crashed] < 0).all()


def test_policy_observation_does_not_depend_on_heading():
    from bfc.envs.rotations import euler_to_quat, quat_to_euler, quat_to_matrix
    from bfc.transforms.observation import PolicyObservation

    obs = PolicyObservation(1, hover_speed=458.0)
    goal = torch.tensor([[0.0, 0.0, 1.5]])
    odom = torch.zeros(1, 18)
    odom[0, 0:3] = torch.tensor([1.0, -0.5, 2.0])
    odom[0, 3:6] = torch.tensor([0.3, 0.2, -0.1])
    odom[0, 9:12] = torch.tensor([0.2, -0.3, 0.4])
    odom[0, 12:15] = torch.tensor([0.1, 0.2, 0.3])
    a = obs.build(odom, goal, torch.zeros(1, 4))
    # turn the whole scene by 2.5 rad about the goal's vertical
    turn = quat_to_matrix(euler_to_quat(torch.tensor([0.0, 0.0, 2.5])))
    turned = odom.clone()
    turned[0, 0:3] = goal[0] + turn @ (odom[0, 0:3] - goal[0])
    turned[0, 3:6] = turn @ odom[0, 3:6]
    q = euler_to_quat(odom[0, 9:12])
    yaw_q = euler_to_quat(torch.tensor([0.0, 0.0, 2.5]))
    w1, x1, y1, z1 = yaw_q
    w2, x2, y2, z2 = q
    prod = torch.stack(
        (
            w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
            w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
            w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
            w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
        )
    )
    turned[0, 9:12] = quat_to_euler(prod)
    b = obs.build(turned, goal, torch.zeros(1, 4))
    torch.testing.assert_close(a, b, atol=1e-5, rtol=1e-5)


def test_env_set_seed_also_seeds_the_transforms(cfg):
    cfg.env.num_envs = 32
    cfg.noise.kind = "gaussian"
    cfg.jd.p0 = 0.5
    a, b = make_env(cfg), make_env(cfg)
    a.set_seed(11)
    b.set_seed(11)
    ra, rb = a.reset(), b.reset()
    assert torch.equal(ra[keys.ODOMETRY], rb[keys.ODOMETRY])  # same JD/CSS starts and the same noise
    b.set_seed(12)
    assert not torch.equal(a.reset()[keys.ODOMETRY], b.reset()[keys.ODOMETRY])


def test_thrust_action_map_is_linear_in_thrust_and_round_trips():
    from bfc.transforms import MotorSpeedAction

    hover = 457.0
    thrust_map, speed_map = MotorSpeedAction(hover, 838.0, "thrust"), MotorSpeedAction(hover, 838.0, "speed")
    a = torch.linspace(-0.45, 1.0, 30)
    w = thrust_map._inv_apply_transform(a)
    torch.testing.assert_close((w / hover) ** 2, 1 + 2 * a)  # thrust is linear in the action
    torch.testing.assert_close(thrust_map.to_action(w), a)
    torch.testing.assert_close(speed_map._inv_apply_transform(a) / hover, (1 + a).clamp(max=838.0 / hover))
    # zero-mean exploration noise leaves the mean thrust where the mean action puts it
    noisy = 0.1 + 0.2 * torch.randn(200_000, generator=torch.Generator().manual_seed(0))
    mean_thrust = (thrust_map._inv_apply_transform(noisy) / hover).pow(2).mean()
    assert mean_thrust.item() == pytest.approx(1.2, abs=0.01)
    assert (speed_map._inv_apply_transform(noisy) / hover).pow(2).mean().item() > 1.23  # the speed map is biased up
    assert (w <= 838.0).all() and thrust_map._inv_apply_transform(torch.tensor([-1.0])).item() == 0.0
    with pytest.raises(ValueError, match="model.action_map"):
        MotorSpeedAction(hover, 838.0, "rpm")


def test_position_integral_accumulates_near_the_goal_clips_and_restarts_per_env(cfg):
    """model.position_integral: the error integrated (world frame) only within the radius, clipped,
    zeroed for the envs that reset and no others; the policy sees it turned into the heading frame."""
    cfg.env.num_envs = 3
    cfg.model.position_integral = True
    env = make_env(cfg, samplers=False, given_starts=True, seed=0)
    obs = find_transform(env, PolicyObservation)
    assert obs.size == 25 and env.observation_spec[keys.OBSERVATION].shape == (3, 25)
    starts = torch.zeros(3, 12)
    starts[:, 0:3] = torch.tensor([[0.1, 0.0, 1.5], [0.0, 0.0, 1.5 - 0.2], [1.5, 0.0, 1.5]])  # 1.5 m: outside
    starts[0, 5] = torch.pi / 2  # yawed by 90 deg: the world +x error is the heading frame's -y
    find_transform(env, GivenStarts).set_starts(starts)
    td = env.reset()
    goal = env.base_env.goal

    def near_error(td):  # all three envs start at rest: slow enough to integrate as settled
        error = td[keys.POSITION] - goal
        return torch.where(error.norm(dim=-1, keepdim=True) < obs.integral_settled_radius, error * obs.dt, 0.0)

    first = near_error(td)  # from the first odometry on: the integral includes the current error
    torch.testing.assert_close(obs.integral, first)
    hover = torch.zeros(3, 4)
    td = env.step(td.set(keys.ACTION, hover))["next"]
    expected = first + near_error(td)
    torch.testing.assert_close(obs.integral, expected)
    assert obs.integral[2].abs().sum() == 0 and obs.integral[0, 0] > 0 and obs.integral[1, 2] < 0
    seen = td[keys.OBSERVATION][:, 22:25] / obs.integral_scale
    torch.testing.assert_close(
        seen[0], torch.stack((0 * expected[0, 0], -expected[0, 0], expected[0, 2])), atol=1e-6, rtol=0
    )
    # clipped at the limit however long an error lasts
    odometry, zero, integral = torch.zeros(1, 18), torch.zeros(1, 3), torch.zeros(1, 3)
    odometry[0, 0:3] = torch.tensor([0.2, -0.1, 0.0])
    for _ in range(1000):
        integral = obs.integrate(integral, odometry, zero)
    assert integral.tolist() == [[obs.integral_limit, -obs.integral_limit, 0.0]]
    # beyond the radius it integrates only while settled: held still 0.5 m off (as a strong wind
    # holds a drone) it does; flying past the same point (1 m/s) it does not
    odometry[0, 0:3] = torch.tensor([0.5, 0.0, 0.0])
    assert obs.integral_radius < 0.5 < obs.integral_settled_radius
    torch.testing.assert_close(obs.integrate(zero, odometry, zero), torch.tensor([[0.5 * obs.dt, 0.0, 0.0]]))
    odometry[0, 3] = -1.0
    assert obs.integrate(zero, odometry, zero).tolist() == [[0.0, 0.0, 0.0]]
    before = obs.integral.clone()
    env.reset(td.clone().set("_reset", torch.tensor([[True], [False], [False]])))  # env 0 back at its start
    assert torch.equal(obs.integral[0], first[0]) and torch.equal(obs.integral[1:], before[1:])


def test_a_start_state_given_to_reset_is_honoured_by_the_sampled_stack():
    """`make_env(cfg).reset(TensorDict(start_state=...))` places the envs exactly, as the base env
    does, whatever JD and CSS would have drawn; NaN entries are still the samplers' (or D's), and a
    partial reset moves only the envs it names."""
    from bfc.config import compose
    from bfc.envs.rotations import quat_to_euler

    env = make_env(compose(["env.num_envs=4"]), seed=0)  # the default: JD, CSS, TDTS, randomisation
    start = torch.zeros(4, 12)
    start[:, 0:3] = torch.tensor([[0.5, -0.5, 1.0], [1.0, 1.0, 2.0], [-1.0, 0.0, 0.7], [0.0, 0.3, 1.2]])
    start[:, 3:6] = torch.tensor([0.3, -0.2, 1.0])
    start[:, 6:9] = torch.tensor([0.5, 0.0, -0.2])
    td = env.reset(TensorDict({keys.START_STATE: start}, batch_size=[4]))
    torch.testing.assert_close(td[keys.POSITION], start[:, 0:3])
    torch.testing.assert_close(quat_to_euler(td[keys.QUATERNION]), start[:, 3:6], atol=1e-5, rtol=0)
    torch.testing.assert_close(td[keys.LINEAR_VELOCITY], start[:, 6:9])
    assert td[keys.OBSERVATION].shape == (4, 41)  # the default: 22, the integral, 4 older commands
    # NaN: drawn (here x, y by CSS); an env outside "_reset" stays where it is
    partial = start.clone()
    partial[:, 0:2] = float("nan")
    partial[:, 2] = 2.5
    mask = torch.tensor([[True], [True], [False], [False]])
    out = env.reset(TensorDict({keys.START_STATE: partial, "_reset": mask}, batch_size=[4]))
    assert (out[keys.POSITION][:2, 2] == 2.5).all() and not torch.equal(out[keys.POSITION][:2, :2], start[:2, :2])
    assert out[keys.POSITION][:2, :2].abs().max() <= 2.0  # CSS's area
    torch.testing.assert_close(env.base_env.observe()[2:, 0:3], start[2:, 0:3])  # the others where they were
    with pytest.raises(ValueError, match=r"start_state must have shape \(4, 12\)"):
        env.reset(TensorDict({keys.START_STATE: torch.zeros(4, 11)}, batch_size=[4]))
    env.close()
