"""The baselines' gains per airframe: the per-env factors a tuning grid flies equal controllers built
one by one with those factors, and every controller name builds the airframe's tuned gains."""

import dataclasses

import pytest
import torch

from bfc.config import airframe_params, builtin_airframes
from bfc.controllers import CONTROLLERS, TUNED, LeeController, LeeGains, LinearMPC, build, tuned_factors
from bfc.controllers.base import Odometry
from bfc.evaluation import fly, protocol_starts

DT = 1 / 250
CANDIDATES = [
    {"position": 0.5, "attitude": 2.0},
    {"position": 1.0, "attitude": 1.0},
    {"position": 2.0, "attitude": 0.5},
]


def per_env(candidates, n):
    factors = {g: torch.tensor([c[g] for c in candidates], dtype=torch.float64) for g in candidates[0]}
    return {g: f.repeat_interleave(n) for g, f in factors.items()}


def test_a_grid_flown_side_by_side_is_each_candidate_flown_alone():
    airframe = airframe_params("crazyflie")
    nominal = dataclasses.asdict(airframe)
    starts = protocol_starts(3, seed=5)
    grid = LeeController(airframe, DT).scale_gains(**per_env(CANDIDATES, 3))
    together = fly(grid, starts.repeat(len(CANDIDATES), 1), seconds=2.0, control_hz=250, nominal=nominal)
    for k, c in enumerate(CANDIDATES):
        alone = fly(LeeController(airframe, DT).scale_gains(**c), starts, seconds=2.0, control_hz=250, nominal=nominal)
        torch.testing.assert_close(together.get("action")[3 * k : 3 * k + 3], alone.get("action"), rtol=0, atol=0)
    # the factors change the flight (the grid is not flying one controller three times)
    assert not torch.equal(together.get("action")[:3], together.get("action")[3:6])


def test_the_mpc_inner_loop_factors_per_env():
    airframe = airframe_params("crazyflie")
    g = torch.Generator().manual_seed(0)
    odometry = torch.zeros(2, 18, dtype=torch.float64)
    odometry[:, 0:3] = torch.tensor([0.3, -0.2, 1.2])
    odometry[:, 9:12] = (torch.rand(1, 3, generator=g, dtype=torch.float64) - 0.5) * 0.6  # roll, pitch, yaw
    odometry[:, 12:15] = torch.rand(1, 3, generator=g, dtype=torch.float64) - 0.5
    goal = torch.tensor([[0.0, 0.0, 1.5]] * 2, dtype=torch.float64)
    both = LinearMPC(airframe, DT).scale_gains(attitude=torch.tensor([0.5, 2.0]), angular_rate=torch.tensor([2.0, 0.5]))
    first = LinearMPC(airframe, DT).scale_gains(attitude=0.5, angular_rate=2.0)
    second = LinearMPC(airframe, DT).scale_gains(attitude=2.0, angular_rate=0.5)
    odo = Odometry.parse(odometry)
    cmd = both.command(odo, goal)
    torch.testing.assert_close(cmd[:1], first.command(Odometry.parse(odometry[:1]), goal[:1]), rtol=1e-3, atol=0.5)
    torch.testing.assert_close(cmd[1:], second.command(Odometry.parse(odometry[1:]), goal[1:]), rtol=1e-3, atol=0.5)
    assert not torch.allclose(cmd[0], cmd[1])


def test_unknown_gain_groups_fail_naming_the_allowed():
    with pytest.raises(ValueError, match="lee gain groups are position, velocity, attitude, angular_rate"):
        LeeController(airframe_params("hummingbird"), DT).scale_gains(yaw=2.0)
    with pytest.raises(ValueError, match="mpc gain groups are attitude, angular_rate"):
        LinearMPC(airframe_params("hummingbird"), DT).scale_gains(position=2.0)


def test_every_tuned_entry_is_a_built_in_airframe_with_known_groups():
    for name, controllers in TUNED.items():
        assert name in builtin_airframes()
        for controller, factors in controllers.items():
            built = build(controller, airframe_params(name), DT, tuned=False)
            assert set(factors) <= set(built.GAIN_GROUPS) and all(f > 0 for f in factors.values())


@pytest.mark.parametrize("name", ["lee", "lee_i", "mpc"])
@pytest.mark.parametrize("airframe", ["hummingbird", "crazyflie", "x500"])
def test_a_controller_name_flies_the_airframes_tuned_gains(name, airframe):
    a = airframe_params(airframe)
    odometry = torch.zeros(1, 18, dtype=torch.float64)
    odometry[:, 0:3] = torch.tensor([0.4, -0.3, 1.1])
    odometry[:, 9:12] = torch.tensor([0.2, -0.1, 0.3])
    odometry[:, 12:15] = torch.tensor([0.5, -0.4, 0.2])
    goal = torch.tensor([[0.0, 0.0, 1.5]], dtype=torch.float64)
    by_name = CONTROLLERS[name](a, DT).command(Odometry.parse(odometry), goal)
    by_hand = build(name, a, DT, tuned=False).scale_gains(**tuned_factors(name, a))
    by_hand = by_hand.command(Odometry.parse(odometry), goal)
    torch.testing.assert_close(by_name, by_hand, rtol=0, atol=0)


def test_the_hummingbirds_factors_act_on_the_published_rotors_set():
    a = airframe_params("hummingbird")
    published, tuned = build("lee", a, DT, tuned=False), CONTROLLERS["lee"](a, DT)
    rotors = torch.tensor((4.0, 4.0, 4.0), dtype=torch.float64)  # lee_controller_hummingbird.yaml, mass ratio 1
    torch.testing.assert_close(published.kp, rotors, rtol=0, atol=1e-12)
    torch.testing.assert_close(tuned.kp, rotors * TUNED["hummingbird"]["lee"].get("position", 1.0), rtol=0, atol=1e-12)
    held = build("lee", a, DT, config=LeeGains(yaw=0.0))  # its own settings, tuned the same way
    assert held.gains.yaw == 0.0
    torch.testing.assert_close(held.kp, tuned.kp, rtol=0, atol=0)
