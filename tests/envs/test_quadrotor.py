"""Physics, interface and robustness of QuadrotorEnv."""

import dataclasses
import math

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from bfc import keys
from bfc.config import EnvConfig
from bfc.envs import EnvParams, QuadrotorEnv
from bfc.envs.rotations import euler_to_quat, quat_to_euler, quat_to_matrix


def air_start(n, z=1.5, **entries):
    start = torch.zeros(n, 12)
    start[:, 2] = z
    for name, value in entries.items():
        idx = {"x": 0, "y": 1, "roll": 3, "pitch": 4, "yaw": 5, "vx": 6, "vy": 7, "vz": 8, "wx": 9, "wy": 10, "wz": 11}
        start[:, idx[name]] = value
    return start


def reset_to(env, start):
    return env.reset(env.reset().set(keys.START_STATE, start))


def fly(env, td, action, steps):
    for _ in range(steps):
        td = env.step(td.set(keys.ACTION, action.expand(env.num_envs, 4).clone()))["next"]
    return td


def test_check_env_specs():
    env = QuadrotorEnv(3, seed=0)
    check_env_specs(env)
    assert env.batch_size == torch.Size([3])
    assert env.action_spec.shape == (3, 4)
    assert float(env.action_spec.space.high.max()) == pytest.approx(838.0)


def test_hover_at_analytic_speed_holds_altitude():
    env = QuadrotorEnv(2, start_motors="hover", seed=0)
    a = env.airframe
    hover = math.sqrt(a.total_mass * a.gravity / (4 * a.motor_constant))
    assert env.hover_speed == pytest.approx(hover)
    assert 450 < hover < 460  # the RotorS Hummingbird hovers at about 453-458 rad/s
    td = reset_to(env, air_start(2))
    z = []
    for _ in range(250):  # 1 s at 250 Hz
        td = fly(env, td, torch.full((4,), hover), 1)
        z.append(td[keys.POSITION][:, 2])
    z = torch.stack(z)
    assert (z - 1.5).abs().max() < 0.02
    assert td[keys.POSITION][:, :2].abs().max() < 1e-3


def test_yaw_sign_cw_pair_faster_yaws_counter_clockwise():
    env = QuadrotorEnv(1, start_motors="hover")
    h = env.hover_speed
    td = reset_to(env, air_start(1))
    td = fly(env, td, torch.tensor([h + 20, h - 20, h + 20, h - 20]), 50)
    assert td[keys.ANGULAR_VELOCITY][0, 2] > 0.1  # positive yaw rate about +z
    assert td[keys.ODOMETRY][0, 11] > 0  # yaw grew
    td = reset_to(env, air_start(1))
    td = fly(env, td, torch.tensor([h - 20, h + 20, h - 20, h + 20]), 50)
    assert td[keys.ANGULAR_VELOCITY][0, 2] < -0.1


@pytest.mark.parametrize("rotor, arm", [(0, (1.0, 0.0)), (1, (0.0, 1.0)), (2, (-1.0, 0.0)), (3, (0.0, -1.0))])
def test_raising_one_rotor_lifts_that_side(rotor, arm):
    env = QuadrotorEnv(1, start_motors="hover")
    cmd = torch.full((4,), env.hover_speed)
    cmd[rotor] += 30
    td = fly(env, reset_to(env, air_start(1)), cmd, 25)
    rot = quat_to_matrix(td[keys.QUATERNION][0])
    arm_world = rot @ torch.tensor([arm[0], arm[1], 0.0])
    assert arm_world[2] > 0.01  # that arm now points upwards
    # torque = r x F: the body rotates about r x z
    expected_axis = torch.linalg.cross(torch.tensor([arm[0], arm[1], 0.0]), torch.tensor([0.0, 0.0, 1.0]))
    assert float(td[keys.ANGULAR_VELOCITY][0] @ expected_axis) > 0.1


def test_free_fall_matches_gravity():
    env = QuadrotorEnv(1, control_hz=250.0)
    td = reset_to(env, air_start(1, z=3.0))
    steps = 75  # 0.3 s
    td = fly(env, td, torch.zeros(4), steps)
    t = steps * env.dt
    assert td[keys.POSITION][0, 2] == pytest.approx(3.0 - 0.5 * 9.81 * t * t, abs=5e-3)
    assert td[keys.ODOMETRY][0, 8] == pytest.approx(-9.81, abs=0.05)  # vertical acceleration channel


def test_motor_lag_reaches_63_percent_after_time_constant():
    # 400 Hz control: tau_up = 12.5 ms is 5 steps and tau_down = 25 ms is 10 steps exactly.
    env = QuadrotorEnv(1, control_hz=400, physics_dt=0.00125)
    td = reset_to(env, air_start(1, z=3.0))
    td = fly(env, td, torch.full((4,), 600.0), 5)
    assert td[keys.MOTOR_SPEEDS][0] == pytest.approx(torch.full((4,), 600 * (1 - math.exp(-1))), rel=1e-5)
    td = fly(env, td, torch.full((4,), 600.0), 200)  # settle
    td = fly(env, td, torch.full((4,), 200.0), 10)
    assert td[keys.MOTOR_SPEEDS][0] == pytest.approx(torch.full((4,), 600 - 400 * (1 - math.exp(-1))), rel=1e-4)


@pytest.mark.parametrize("yaw_weight", [0.0, 0.1])
def test_reward_follows_the_documented_formula(yaw_weight):
    """The batched NumPy reward equals RewardParams' formula written out in torch."""
    n = 32
    env = QuadrotorEnv(n, start_motors="hover", reward={"yaw": yaw_weight}, seed=0)
    g = torch.Generator().manual_seed(4)
    start = air_start(n, z=1.0)
    start[:, 0:2] = torch.rand(n, 2, generator=g) * 2 - 1
    start[:, 3:6] = (torch.rand(n, 3, generator=g) - 0.5) * torch.tensor([1.0, 1.0, 6.0])
    start[:, 6:12] = torch.randn(n, 6, generator=g) * 0.5
    td = reset_to(env, start)
    action = env.hover_speed * (0.8 + 0.4 * torch.rand(n, 4, generator=g))
    out = env.step(td.set(keys.ACTION, action))["next"]
    rp, h = env.reward_params, env.hover_speed
    q = out[keys.QUATERNION].double()
    dist = (out[keys.POSITION].double() - torch.tensor([0.0, 0.0, 1.5], dtype=torch.float64)).norm(dim=-1)
    w = out[keys.ANGULAR_VELOCITY].double()
    penalty = (
        rp.position * dist
        + rp.tilt * (1 - quat_to_matrix(q)[:, 2, 2])
        + rp.yaw * (1 - quat_to_euler(q)[:, 2].cos())
        + rp.velocity * out[keys.LINEAR_VELOCITY].double().square().sum(-1)
        + rp.angular_velocity * w.square().sum(-1)
        + rp.yaw_rate * w[:, 2].square()
        + rp.action * ((action.double() - h) / h).square().sum(-1)
    )
    expected = rp.scale * (
        rp.alive * (-penalty / rp.alive).exp() + rp.precision * (-((dist / rp.precision_radius) ** 2)).exp()
    )
    assert not out[keys.TERMINATED].any()
    torch.testing.assert_close(out["reward"].squeeze(-1).double(), expected, rtol=1e-4, atol=1e-7)


@pytest.mark.parametrize("yaw", [0.0, math.pi / 2, 2.5])
def test_rotor_drag_opposes_the_velocity_whatever_the_heading(yaw):
    """Drag is computed in the body frame and applied there: in the world it must oppose v."""
    drag = QuadrotorEnv(1, start_motors="hover")
    free = QuadrotorEnv(
        1, start_motors="hover", airframe={"rotor_drag_coefficient": 0.0, "rolling_moment_coefficient": 0.0}
    )
    start = air_start(1, yaw=yaw, vx=2.0, vy=-1.0)
    steps = 25  # 0.1 s: short enough that the rolling moment has not tilted the thrust noticeably
    v, v_free = (
        fly(e, reset_to(e, start), torch.full((4,), e.hover_speed), steps)[keys.LINEAR_VELOCITY][0]
        for e in (drag, free)
    )
    dv, v0 = (v - v_free)[:2].double(), torch.tensor([2.0, -1.0], dtype=torch.float64)
    assert float(dv @ -v0) / (float(dv.norm()) * float(v0.norm())) > 0.99
    a = drag.airframe
    expected = a.rotor_drag_coefficient * 4 * drag.hover_speed * float(v0.norm()) / a.total_mass * steps * drag.dt
    assert float(dv.norm()) == pytest.approx(expected, rel=0.1)


def test_reset_to_given_start_is_exact():
    env = QuadrotorEnv(4, seed=0)
    g = torch.Generator().manual_seed(3)
    start = torch.rand(4, 12, generator=g) * 2 - 1
    start[:, 2] += 2.0
    td = reset_to(env, start)
    odom = td[keys.ODOMETRY]
    torch.testing.assert_close(odom[:, 0:3], start[:, 0:3])
    torch.testing.assert_close(odom[:, 9:12], start[:, 3:6])
    torch.testing.assert_close(odom[:, 3:6], start[:, 6:9])
    torch.testing.assert_close(odom[:, 12:15], start[:, 9:12])
    torch.testing.assert_close(quat_to_euler(td[keys.QUATERNION]), start[:, 3:6])
    torch.testing.assert_close(odom[:, 6:9], torch.zeros(4, 3))


def test_nan_entries_of_a_start_come_from_the_task_distribution():
    env = QuadrotorEnv(64, seed=0)
    start = torch.full((64, 12), float("nan"))
    start[:, 0] = 0.5  # only x is given
    td = reset_to(env, start)
    assert (td[keys.POSITION][:, 0] == 0.5).all()
    assert td[keys.POSITION][:, 1].std() > 0.5  # y drawn from D: uniform in [-2, 2]
    torch.testing.assert_close(td[keys.POSITION][:, 2], torch.full((64,), env.ground_height))


def test_default_reset_is_on_the_ground_level_at_rest():
    env = QuadrotorEnv(128, seed=1)
    td = env.reset()
    pos = td[keys.POSITION]
    assert pos[:, :2].abs().max() <= 2.0 and pos[:, :2].std() > 0.5
    torch.testing.assert_close(pos[:, 2], torch.full((128,), env.ground_height))
    torch.testing.assert_close(td[keys.ODOMETRY][:, 9:11], torch.zeros(128, 2))
    # resting on the ground before take-off is not a crash
    td = fly(env, td, torch.zeros(4), 100)
    assert not td[keys.DONE].any()


def test_partial_reset_leaves_other_envs_bit_identical():
    env = QuadrotorEnv(4, start_motors="hover", seed=0)
    td = fly(env, reset_to(env, air_start(4)), torch.full((4,), 470.0), 20)
    before = td.clone()
    mask = torch.tensor([True, False, True, False]).unsqueeze(-1)
    after = env.reset(td.clone().set("_reset", mask).set(keys.START_STATE, air_start(4, z=2.5)))
    for key in (keys.ODOMETRY, keys.POSITION, keys.QUATERNION, keys.MOTOR_SPEEDS, keys.LINEAR_VELOCITY):
        assert torch.equal(after[key][1], before[key][1]) and torch.equal(after[key][3], before[key][3])
    assert (after[keys.POSITION][[0, 2], 2] == 2.5).all()
    # and the untouched envs go on exactly as an env that was never partially reset
    ref = QuadrotorEnv(4, start_motors="hover", seed=0)
    ref_td = fly(ref, reset_to(ref, air_start(4)), torch.full((4,), 470.0), 20)
    a = fly(env, after, torch.full((4,), 470.0), 10)
    b = fly(ref, ref_td, torch.full((4,), 470.0), 10)
    assert torch.equal(a[keys.ODOMETRY][[1, 3]], b[keys.ODOMETRY][[1, 3]])


def test_acceleration_channels_match_finite_differences():
    env = QuadrotorEnv(3, seed=0)
    start = air_start(3, roll=0.3, pitch=-0.2, wx=1.0)
    td = reset_to(env, start)
    g = torch.Generator().manual_seed(0)
    for _ in range(30):
        prev = td[keys.ODOMETRY].clone()
        td = fly(env, td, 400 + 100 * torch.rand(4, generator=g), 1)
        odom = td[keys.ODOMETRY]
        torch.testing.assert_close(odom[:, 6:9], (odom[:, 3:6] - prev[:, 3:6]) / env.dt, atol=1e-3, rtol=1e-3)
        torch.testing.assert_close(odom[:, 15:18], (odom[:, 12:15] - prev[:, 12:15]) / env.dt, atol=1e-2, rtol=1e-3)


def test_seeding_reproduces_trajectories():
    def run(seed):
        env = QuadrotorEnv(8)
        env.set_seed(seed)
        torch.manual_seed(seed)
        return env.rollout(100, break_when_any_done=False)

    a, b, c = run(7), run(7), run(8)
    assert torch.equal(a["next", keys.ODOMETRY], b["next", keys.ODOMETRY])
    assert not torch.equal(a[keys.ODOMETRY][:, 0], c[keys.ODOMETRY][:, 0])


def test_wrong_action_shape_and_nan_actions_raise():
    env = QuadrotorEnv(2)
    td = env.reset()
    with pytest.raises(ValueError, match=r"action must have shape \(2, 4\)"):
        env.step(_bad_shape())
    bad = torch.full((2, 4), 400.0)
    bad[1, 2] = float("nan")
    with pytest.raises(ValueError, match=r"NaN or infinite motor speeds for envs \[1\]"):
        env.step(td.set(keys.ACTION, bad))


def _bad_shape():
    from tensordict import TensorDict

    return TensorDict({keys.ACTION: torch.zeros(2, 3)}, batch_size=[2])


def test_tipping_over_on_the_ground_and_leaving_the_box_are_crashes():
    env = QuadrotorEnv(3)
    start = torch.zeros(3, 12)
    start[:, 2] = env.ground_height
    start[0, 3] = math.radians(80)  # on its side, touching the floor: tipped over
    start[1, 0] = 5.5  # outside the allowed box
    start[2, 2] = 0.3
    start[2, 8] = -4.0  # falling fast towards the floor: hits hard
    td = reset_to(env, start)
    done_at = torch.full((3,), -1)
    for t in range(60):
        td = fly(env, td, torch.zeros(4), 1)
        done_at = torch.where((done_at < 0) & td[keys.TERMINATED].squeeze(-1), t, done_at)
    assert (done_at >= 0).all(), done_at
    assert done_at[0] == 0 and done_at[1] == 0
    assert td["reward"].shape == (3, 1)


def test_time_limit_truncates():
    env = QuadrotorEnv(2, episode_seconds=0.1, start_motors="hover")
    td = reset_to(env, air_start(2))
    for i in range(env.max_episode_steps):
        td = fly(env, td, torch.full((4,), env.hover_speed), 1)
        assert bool(td[keys.TRUNCATED].all()) == (i == env.max_episode_steps - 1)
    assert not td[keys.TERMINATED].any() and td[keys.DONE].all()


def test_nan_physics_terminates_that_env_only():
    env = QuadrotorEnv(3, start_motors="hover")
    td = reset_to(env, air_start(3))
    env._physics_np[1, 5] = float("nan")  # corrupt one env's state, as a blown-up integration would
    td = fly(env, td, torch.full((4,), env.hover_speed), 1)
    assert td[keys.TERMINATED].squeeze(-1).tolist() == [False, True, False]
    assert env.physics_failures == 1
    assert torch.isfinite(td[keys.ODOMETRY]).all() and torch.isfinite(td["reward"]).all()


def test_bad_constructor_values_name_the_key():
    with pytest.raises(ValueError, match="env.num_envs"):
        QuadrotorEnv(0)
    with pytest.raises(ValueError, match="env.control_hz"):
        QuadrotorEnv(1, control_hz=333)
    with pytest.raises(ValueError, match="airframe.body_mass"):
        QuadrotorEnv(1, airframe={"body_mass": -1})
    with pytest.raises(ValueError, match="allowed keys"):
        QuadrotorEnv(1, reward={"positon": 1.0})


def test_the_env_takes_its_params_dataclass_or_its_fields_by_keyword():
    params = EnvParams(control_hz=250.0, start_motors="hover", airframe={"body_mass": 0.9})
    a, b = QuadrotorEnv(2, params), QuadrotorEnv(2, control_hz=250.0, start_motors="hover", airframe={"body_mass": 0.9})
    assert a.params == b.params and a.airframe.body_mass == 0.9 and a.substeps == 2
    changed = QuadrotorEnv(2, params, episode_seconds=1.0)  # a keyword changes one field of `params`
    assert changed.max_episode_steps == 250 and changed.start_motors == "hover"
    assert params.episode_seconds == 5.0  # the caller's params are left alone
    with pytest.raises(ValueError, match="EnvParams: .*unexpected keyword.*allowed keys: control_hz"):
        QuadrotorEnv(1, control_rate=250.0)
    # the config's env section extends EnvParams: one default per value, the run's own where it differs
    run, env = EnvConfig(), EnvParams()
    differ = {f.name for f in dataclasses.fields(EnvParams) if getattr(run, f.name) != getattr(env, f.name)}
    assert differ == {"physics_dt", "reward", "randomize"}


def test_airframe_overrides_reach_the_physics():
    heavy = QuadrotorEnv(1, airframe={"body_mass": 0.9})
    assert heavy.hover_speed > QuadrotorEnv(1).hover_speed
    assert float(heavy.model.body_subtreemass[1]) == pytest.approx(0.9 + 4 * 0.009 + 0.015)


def test_rotation_helpers_round_trip():
    rpy = torch.tensor([[0.3, -0.5, 2.0], [-1.0, 0.2, -3.0]], dtype=torch.float64)
    torch.testing.assert_close(quat_to_euler(euler_to_quat(rpy)), rpy)


def test_randomized_external_force_is_drawn_per_episode_within_its_range_and_reproducible():
    from bfc.envs import RandomizeParams

    def forces(seed):
        env = QuadrotorEnv(64, randomize={"external_force": 1.5}, seed=seed)
        env.reset()
        first = env.external_force.clone()
        td = env.reset()
        second = env.external_force.clone()
        env.close()
        return first, second, td

    first, second, _ = forces(3)
    size = first.norm(dim=-1)
    assert (first[:, 2] == 0).all() and size.max() <= 1.5 + 1e-6 and size.max() > 1.0 and size.min() < 0.5
    assert not torch.equal(first, second)  # a new force every episode
    assert torch.equal(forces(3)[0], first) and not torch.equal(forces(4)[0], first)  # by seed
    env = QuadrotorEnv(4, seed=3)  # off by default: no force, no draw
    env.reset()
    assert (env.external_force == 0).all()
    with pytest.raises(ValueError, match="env.randomize.external_force"):
        RandomizeParams(external_force=-1.0)


def test_evaluation_envs_leave_training_randomisation_off():
    from bfc.config import compose
    from bfc.factory import make_env

    cfg = compose(["env.num_envs=8", "env.randomize.external_force=1.0"])
    train_env, eval_env = make_env(cfg, seed=0), make_env(cfg, seed=0, samplers=False)
    train_env.reset()
    eval_env.reset()
    assert (train_env.base_env.external_force != 0).any() and (eval_env.base_env.external_force == 0).all()


AIRFRAME_RANDOM = {"mass": (0.7, 1.3), "inertia": (1.0, 1.5), "motor_constant": (0.8, 1.2), "motor_lag": (1.0, 3.0)}


def test_randomized_airframe_is_drawn_per_episode_within_its_ranges_and_reproducible():
    from bfc.envs import RandomizeParams

    def draws(seed):
        env = QuadrotorEnv(64, randomize=AIRFRAME_RANDOM, seed=seed)
        env.reset()
        first = env.airframe_scale
        env.reset()
        second = env.airframe_scale
        env.close()
        return first, second

    first, second = draws(3)
    for name, (low, high) in AIRFRAME_RANDOM.items():
        v = first[name]
        assert v.min() >= low - 1e-12 and v.max() <= high + 1e-12, name
        assert v.max() - v.min() > 0.6 * (high - low), name  # spread over the range
        assert not torch.equal(v, second[name]), name  # a new airframe every episode
        assert torch.equal(draws(3)[0][name], v) and not torch.equal(draws(4)[0][name], v), name  # by seed
    assert all(len(v.unique()) == 64 for v in first.values())  # continuous: one draw per env
    off = QuadrotorEnv(4, seed=3)
    off.reset()
    assert all((v == 1).all() for v in off.airframe_scale.values())
    with pytest.raises(ValueError, match="env.randomize.mass"):
        RandomizeParams(mass=(1.3, 0.7))


@pytest.mark.parametrize(
    "randomize, airframe",
    [
        ({"mass": (1.3, 1.3)}, {"body_mass": 0.68 * 1.3}),
        ({"inertia": (1.5, 1.5)}, {"inertia": (0.0105, 0.0105, 0.018)}),
    ],
)
def test_randomized_mass_and_inertia_fly_as_the_compiled_body(randomize, airframe):
    """A randomised mass or inertia is a gain on the body wrench of the one compiled model: over a
    short flight it moves as a model compiled with that mass or inertia does (within 0.5 mm: the
    gains use the rigid-body inertia of params.py, and the composite body's centre of mass shifts
    slightly with the base link's mass)."""
    start = torch.zeros(4, 12, dtype=torch.float64)
    start[:, 2], start[:, 3], start[:, 9] = 1.5, 0.4, 1.0  # tilted and rolling
    commands = torch.Generator().manual_seed(0)
    paths = []
    for env in (
        QuadrotorEnv(4, randomize=randomize),
        QuadrotorEnv(4, airframe=airframe),  # motors start at rest in both
    ):
        td = env.reset(TensorDict({"start_state": start}, batch_size=[4]))
        commands.manual_seed(0)
        for _ in range(20):
            noise = 0.1 * torch.randn(4, 4, generator=commands)
            td = env.step(td.set("action", (457.9 * (1 + noise)).float()))["next"]
        paths.append(torch.cat((td["state", "position"], td["state", "quaternion"]), -1))
        moved = (td["state", "position"] - start[:, :3].float()).norm(dim=-1)
        env.close()
    assert moved.min() > 0.01  # it flew
    torch.testing.assert_close(paths[0], paths[1], atol=5e-4, rtol=0)


def test_randomized_airframe_changes_the_flown_physics():
    """Under the nominal hover command, a heavier or weaker-motored body sinks, a lighter or
    stronger one climbs, in proportion; a slower motor lags more behind a step in the command."""
    env = QuadrotorEnv(256, randomize=AIRFRAME_RANDOM, start_motors="hover", seed=0)
    start = torch.zeros(256, 12, dtype=torch.float64)
    start[:, 2] = 1.5
    td = env.reset(TensorDict({"start_state": start}, batch_size=[256]))
    scale = env.airframe_scale
    td["action"] = torch.full((256, 4), env.hover_speed * 1.1, dtype=torch.float32)
    for _ in range(10):
        td = env.step(td)["next"].set("action", td["action"])
    vz = td["state", "linear_velocity"][:, 2].double()
    # thrust / weight at 1.1 x hover speed, nominal thrust and weight ratio k / m (rotors and imu unscaled)
    a = env.airframe
    mass = a.body_mass * scale["mass"] + 4 * a.rotor_mass + a.imu_mass
    ratio = 1.21 * scale["motor_constant"] * a.total_mass / mass
    assert torch.corrcoef(torch.stack((vz, ratio)))[0, 1] > 0.9
    # the motor lag: after the step 0 -> hover, slower motors are further from the command
    env2 = QuadrotorEnv(64, randomize={"motor_lag": (1.0, 3.0)}, seed=1)
    td = env2.reset(TensorDict({"start_state": start[:64]}, batch_size=[64]))
    td["action"] = torch.full((64, 4), env2.hover_speed, dtype=torch.float32)
    env2.step(td)
    lagging = env2.hover_speed - env2._motor[:, 0]
    assert torch.corrcoef(torch.stack((lagging, env2.airframe_scale["motor_lag"])))[0, 1] > 0.95
