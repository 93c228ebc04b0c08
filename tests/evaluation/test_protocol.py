"""The success rule, the protocol's starts, and flying controllers through `fly`."""

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule

from bfc import keys
from bfc.evaluation import fly, protocol_starts, success, time_to_success

DT = 0.01


def trajectory(positions, goal=(0.0, 0.0, 1.5)):
    """A hand-built (n, T) trajectory at 100 Hz."""
    pos = torch.as_tensor(positions, dtype=torch.float32)
    n, t = pos.shape[:2]
    return TensorDict(
        {
            keys.STATE: {"position": pos},
            keys.GOAL: torch.tensor(goal).expand(n, t, 3),
            "alive": torch.ones(n, t, dtype=torch.bool),
            "time": (torch.arange(1, t + 1) * DT).expand(n, t),
        },
        batch_size=[n, t],
    )


def path(inside_steps, total=300, start_outside=10, offset=(0.05, -0.05, 0.05)):
    goal = torch.tensor([0.0, 0.0, 1.5])
    pos = (goal + torch.tensor([1.0, 0.0, 0.0])).repeat(total, 1)
    pos[start_outside : start_outside + inside_steps] = goal + torch.tensor(offset)
    return pos


def test_exactly_hold_seconds_inside_succeeds_and_one_step_short_fails():
    tr = trajectory(torch.stack([path(100), path(99)]))  # 1 s = 100 steps at 100 Hz
    assert success(tr, hold_seconds=1.0).tolist() == [True, False]
    t = time_to_success(tr)
    assert t[0].item() == pytest.approx(11 * DT) and math.isnan(t[1].item())


def test_leaving_and_reentering_restarts_the_count():
    p = path(60)
    p[80:140] = torch.tensor([0.0, 0.0, 1.5])  # 60 more steps inside after 10 outside
    assert not success(trajectory(p[None])).item()
    p[80:180] = torch.tensor([0.0, 0.0, 1.5])  # now a full 100-step stay
    assert success(trajectory(p[None])).item()


def test_one_axis_outside_fails():
    assert not success(trajectory(path(200, offset=(0.0, 0.0, 0.11))[None])).item()
    assert success(trajectory(path(200, offset=(0.099, -0.099, 0.099))[None])).item()


def test_a_crash_before_the_hold_fails():
    tr = trajectory(path(200)[None])
    tr["alive"][0, 50:] = False
    assert not success(tr).item()


def test_protocol_starts_are_deterministic_and_in_range():
    a, b, c = protocol_starts(100, 0), protocol_starts(100, 0), protocol_starts(100, 1)
    assert torch.equal(a, b) and not torch.equal(a, c)
    assert a.shape == (100, 12)
    assert (a[:, :2].abs() <= 2).all() and (a[:, 2] >= 0.5).all() and (a[:, 2] <= 3).all()
    assert (a[:, 3:5].abs() <= math.radians(60) + 1e-6).all() and (a[:, 5].abs() <= math.pi + 1e-6).all()
    assert (a[:, 6:] == 0).all()
    assert a[:, 3:5].abs().max() > math.radians(55)  # the ranges are used, not just allowed


class Hover(torch.nn.Module):
    """A hand-written controller: every motor at the hover speed (rad/s)."""

    def __init__(self, speed):
        super().__init__()
        self.speed = speed

    def forward(self, odometry):
        return torch.full((odometry.shape[0], 4), self.speed)


class AltitudeHold(torch.nn.Module):
    """A hand-written hover controller for level flight: PD on height, the same speed on all
    motors (thrust ~ speed^2, so the speed goes as the square root of the thrust wanted)."""

    def __init__(self, speed, kp=4.0, kd=3.0):
        super().__init__()
        self.speed, self.kp, self.kd = speed, kp, kd

    def forward(self, odometry, goal):
        accel = self.kp * (goal[:, 2] - odometry[:, 2]) - self.kd * odometry[:, 5]  # m/s^2 wanted
        thrust = (1 + accel / 9.81).clamp(0.0, 3.0)
        return (self.speed * thrust.sqrt()).unsqueeze(-1).expand(-1, 4)


def hover_controller(hold=False):
    from bfc.envs.params import AirframeParams

    speed = AirframeParams().hover_speed
    if hold:
        return TensorDictModule(AltitudeHold(speed), in_keys=[keys.ODOMETRY, keys.GOAL], out_keys=[keys.ACTION])
    return TensorDictModule(Hover(speed), in_keys=[keys.ODOMETRY], out_keys=[keys.ACTION])


def test_fly_hover_controller_from_level_start_at_goal_succeeds_and_on_its_back_fails():
    starts = torch.zeros(2, 12)
    starts[:, 2] = 1.5
    starts[1, 3] = math.pi  # upside down, motors off at the start
    tr = fly(hover_controller(hold=True), starts, seconds=2.0)
    assert tr.shape == (2, 500)  # 2 s at 250 Hz: the protocol's rate for controllers
    for key in (keys.POSITION, keys.QUATERNION, keys.ODOMETRY, keys.ACTION, "time"):
        assert key in tr.keys(True)
    # motors spin up from rest, so the drone sags a little before it holds: it stays in the box
    assert success(tr).tolist() == [True, False]
    assert not bool(tr["alive"][1, -1])


def test_fly_states_match_the_envs_own_rollout():
    from bfc.envs import QuadrotorEnv

    starts = protocol_starts(3, seed=5)
    tr = fly(hover_controller(), starts, seconds=0.2)
    env = QuadrotorEnv(3, control_hz=250.0, episode_seconds=1.0)  # fly: modules at 250 Hz
    td = env.reset(env.reset().set(keys.START_STATE, starts))
    for t in range(tr.shape[1]):
        td = env.step(td.set(keys.ACTION, torch.full((3, 4), env.hover_speed)))["next"]
        torch.testing.assert_close(tr[keys.POSITION][:, t], td[keys.POSITION])


def test_fly_noise_corrupts_what_the_controller_sees_not_the_judgement():
    starts = torch.zeros(4, 12)
    starts[:, 2] = 1.5
    clean = fly(hover_controller(), starts, seconds=1.0)
    noisy = fly(hover_controller(), starts, seconds=1.0, noise={"kind": "gaussian", "std": 0.2, "elements": "position"})
    # the hover controller ignores its input, so the flight (ground truth) is identical...
    assert torch.equal(clean[keys.POSITION], noisy[keys.POSITION])
    # ...while what it saw was corrupted, and success is judged on the truth
    assert (noisy[keys.ODOMETRY][..., :3] - clean[keys.ODOMETRY][..., :3]).std() > 0.15
    assert torch.equal(success(clean), success(noisy))


def test_fly_takes_its_conditions_whole_or_field_by_field():
    from bfc.factory import FlightConditions, make_flight_env

    starts = protocol_starts(4, seed=2)
    flight = FlightConditions(seconds=0.5, noise={"kind": "gaussian", "std": 0.1}, action_delay=0.008, seed=3)
    whole = fly("lee", starts, flight=flight)
    by_field = fly("lee", starts, seconds=0.5, noise={"kind": "gaussian", "std": 0.1}, action_delay=0.008, seed=3)
    assert whole.shape == (4, 125) and torch.equal(whole[keys.POSITION], by_field[keys.POSITION])
    env = make_flight_env(2, flight, control_hz=100.0)
    assert env.base_env.max_episode_steps == 150  # the episode runs a second past the flight
    for bad, match in (({"seconds": 0}, "seconds must be > 0"), ({"action_delay": -0.01}, "action_delay")):
        with pytest.raises(ValueError, match=match):
            fly("lee", starts, **bad)
    with pytest.raises(ValueError, match="FlightConditions: .*allowed keys: seconds"):
        fly("lee", starts, second=1.0)


def test_fly_rejects_bad_input(tmp_path):
    with pytest.raises(FileNotFoundError, match="no policy file"):
        fly(tmp_path / "missing.pt", protocol_starts(2))
    bogus = tmp_path / "bogus.pt"
    torch.save({"weights": torch.zeros(3)}, bogus)
    with pytest.raises(ValueError, match="not a bfc policy file"):
        fly(bogus, protocol_starts(2))
    with pytest.raises(ValueError, match="starts must have shape"):
        fly(hover_controller(), torch.zeros(2, 11))


def test_policy_files_fly_with_their_own_action_map(tmp_path):
    """A policy flies with the action map its file records: the shipped one with thrust, the same
    weights recorded with the speed map with speed."""
    from pathlib import Path

    from bfc.envs import AirframeParams

    shipped = Path(__file__).resolve().parents[2] / "pretrained" / "policy.pt"
    payload = torch.load(shipped, weights_only=True)
    assert payload["spec"]["action_map"] == "thrust"
    payload["spec"]["action_map"] = "speed"
    old = tmp_path / "speed.pt"
    torch.save(payload, old)
    starts = protocol_starts(4, seed=3)
    thrust = fly(shipped, starts, seconds=0.05).get(keys.ACTION)[:, 0].double()
    speed = fly(old, starts, seconds=0.05).get(keys.ACTION)[:, 0].double()
    hover = AirframeParams().hover_speed
    # the same first action a, mapped two ways: (w_t / h)^2 - 1 = 2 a and w_s / h - 1 = a
    # (where neither map clipped it to [0, 838] rad/s)
    free = (thrust > 1) & (thrust < 837) & (speed > 1) & (speed < 837)
    assert free.sum() >= 4
    torch.testing.assert_close(((thrust / hover) ** 2 - 1)[free], (2 * (speed / hover - 1))[free], atol=1e-4, rtol=1e-4)
    assert not torch.allclose(thrust, speed)


@pytest.mark.parametrize(
    ("overrides", "expected"),
    [([], 0.01), (["env.physics_dt=0.005"], 0.005), (["eval.physics_dt=0.002"], 0.002)],
)
def test_validation_flies_the_training_step_unless_told(overrides, expected):
    """In-training validation flies the simulator the policy learns in (eval.physics_dt null);
    a given eval.physics_dt (evaluate.py's reference 0.002 s, say) replaces it."""
    from bfc.config import compose
    from bfc.evaluation.evaluator import ProtocolEvaluator

    evaluator = ProtocolEvaluator(compose([*overrides, "eval.num_starts=2"]))
    assert evaluator.env.base_env.physics_dt == pytest.approx(expected)
    assert evaluator.steps == 1000  # 10 s at 100 Hz whatever the physics step
    evaluator.close()
