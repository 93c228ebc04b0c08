"""The mixer, the Lee controller and the linear MPC, flown through the evaluation harness."""

import math
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from bfc import keys
from bfc.controllers import CONTROLLERS, LeeController, LinearMPC, Mixer, MPCParams
from bfc.envs import AirframeParams
from bfc.evaluation import fly, success

AIRFRAME = AirframeParams()
DT = 1 / 250


def level_starts(*offsets):
    """Level starts at rest at goal + offset."""
    s = torch.zeros(len(offsets), 12)
    s[:, 0:3] = torch.tensor([0.0, 0.0, 1.5]) + torch.tensor(offsets, dtype=torch.float32)
    return s


def test_mixer_round_trip_reproduces_thrust_and_torques():
    mixer = Mixer(AIRFRAME)
    g = torch.Generator().manual_seed(0)
    weight = AIRFRAME.total_mass * AIRFRAME.gravity
    thrust = weight * (0.7 + 0.6 * torch.rand(64, generator=g, dtype=torch.float64))
    torque = (torch.rand(64, 3, generator=g, dtype=torch.float64) - 0.5) * torch.tensor([0.1, 0.1, 0.02])
    speeds = mixer(thrust, torque)
    assert ((speeds > 0) & (speeds < AIRFRAME.max_rotor_speed)).all()  # feasible: nothing clipped
    t2, tau2 = mixer.wrench(speeds)
    torch.testing.assert_close(t2, thrust)
    torch.testing.assert_close(tau2, torque)


def test_mixer_hover_and_clipping():
    mixer = Mixer(AIRFRAME)
    weight = torch.tensor([AIRFRAME.total_mass * AIRFRAME.gravity], dtype=torch.float64)
    hover = mixer(weight, torch.zeros(1, 3, dtype=torch.float64))
    torch.testing.assert_close(hover, torch.full((1, 4), AIRFRAME.hover_speed, dtype=torch.float64))
    huge = mixer(weight * 100, torch.tensor([[5.0, 0.0, 0.0]], dtype=torch.float64))
    assert huge.min() >= 0 and huge.max() <= AIRFRAME.max_rotor_speed
    # past the top, the thrust gives way and the torque is kept
    torque = torch.tensor([[0.05, -0.03, 0.004]], dtype=torch.float64)
    saturated = mixer(weight * 3.5, torque)
    thrust, kept = mixer.wrench(saturated)
    assert saturated.max().item() == pytest.approx(AIRFRAME.max_rotor_speed) and thrust.item() < weight.item() * 3.5
    torch.testing.assert_close(kept, torque)
    with pytest.raises(ValueError, match="thrust"):
        mixer(weight, torch.zeros(1, 4, dtype=torch.float64))


def test_positive_roll_torque_speeds_up_the_left_rotor():
    mixer = Mixer(AIRFRAME)
    weight = torch.tensor([AIRFRAME.total_mass * AIRFRAME.gravity], dtype=torch.float64)
    w = mixer(weight, torch.tensor([[0.02, 0.0, 0.0]], dtype=torch.float64))[0]
    assert w[1] > w[0] > w[3]  # motor 1 is left (+y): +x torque lifts it, motor 3 (right) slows
    assert w[0].item() == pytest.approx(w[2].item())


@pytest.mark.parametrize("name", sorted(CONTROLLERS))
def test_holds_a_hover_at_the_goal_and_brings_a_1m_offset_into_the_box(name):
    starts = level_starts((0, 0, 0), (1, 0, 0), (0, -1, 0), (0, 0, 1), (0, 0, -1), (0.6, 0.6, 0.5))
    flights = fly(name, starts, seconds=10.0)
    assert flights.get("alive")[:, -1].all()
    pos = flights.get(keys.POSITION)
    # the start at the goal (motors at rest: a dip while they spin up) stays well inside the box,
    # and holds within 1 cm over the last 5 s
    hover_error = (pos[0] - torch.tensor([0.0, 0.0, 1.5])).norm(dim=-1)
    assert hover_error.max() < 0.05 and hover_error[-1250:].max() < 0.01
    ok = success(flights)
    assert ok.all(), ok
    # and the offset starts end close to the goal
    assert (pos[:, -1] - torch.tensor([0.0, 0.0, 1.5])).norm(dim=-1).max() < 0.05


def test_lee_recovers_a_tilted_start():
    start = level_starts((0.5, -0.5, 0.5))
    start[0, 3:6] = torch.tensor([math.radians(45), math.radians(-30), math.radians(120)])
    assert success(fly("lee", start, seconds=10.0)).all()


def run_steps(controller, starts, steps):
    """Fly by hand, checking the MPC's input after every control step."""
    from bfc.factory import find_transform, make_flight_env
    from bfc.transforms import GivenStarts

    env = make_flight_env(starts.shape[0], control_hz=250.0, seed=0)
    find_transform(env, GivenStarts).set_starts(starts)
    td = env.reset()
    lo, hi = controller.model.lower, controller.model.upper
    for _ in range(steps):
        td = controller(td)
        u = controller._u_prev
        assert torch.isfinite(u).all()
        assert ((u >= lo - 1e-12) & (u <= hi + 1e-12)).all()
        assert torch.isfinite(td[keys.ACTION]).all()
        td = env.step(td)["next"].clone()
    env.close()
    return td


def test_mpc_respects_its_input_limits_in_every_step():
    starts = level_starts((2, -2, 1.5), (-2, 2, -1.0), (0, 0, 0))
    starts[:, 3:5] = torch.tensor([[0.6, -0.6], [-0.8, 0.3], [0.0, 0.0]])
    mpc = LinearMPC(AIRFRAME, DT)
    run_steps(mpc, starts, 500)
    assert mpc.solves == 200 and mpc.fallbacks == 0  # 2 s at 100 Hz


@pytest.mark.parametrize("failure", ["status", "nan"])
def test_mpc_falls_back_to_lqr_when_the_solver_fails(monkeypatch, failure):
    """A failed solve (a bad status, or a non-finite solution) is flown by the LQR, clipped."""
    import osqp

    def failed_solve(self, raise_error=None):
        n = 2 * 3 * MPCParams().horizon  # 2 envs x the stacked inputs
        status = osqp.SolverStatus.OSQP_PRIMAL_INFEASIBLE if failure == "status" else osqp.SolverStatus.OSQP_SOLVED
        return SimpleNamespace(x=np.full(n, np.nan), info=SimpleNamespace(status_val=status))

    monkeypatch.setattr(osqp.OSQP, "solve", failed_solve)
    mpc = LinearMPC(AIRFRAME, DT)
    td = run_steps(mpc, level_starts((0.5, 0.0, 0.0), (0.0, 0.0, 0.0)), 1000)
    assert mpc.fallbacks == 2 * mpc.solves > 0
    # the LQR backup still flies to the goal
    assert (td[keys.POSITION] - torch.tensor([0.0, 0.0, 1.5])).norm(dim=-1).max() < 0.1


def test_controllers_reject_bad_settings():
    with pytest.raises(ValueError, match="mpc.horizon"):
        MPCParams(horizon=0)
    with pytest.raises(ValueError, match="thrust"):
        MPCParams(thrust_min=30.0)
    with pytest.raises(ValueError, match="dt"):
        LeeController(AIRFRAME, 0.0)
