"""bfc's policies flown in RotorPy (bfc.evaluation.rotorpy_sim): the flight path end to end, the
mapping's signs against bfc's own env, RotorPy's batched vehicle against its reference one, and
evaluate.py's `sim` keys."""

import dataclasses
import importlib.util
import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from bfc.config import airframe_params
from bfc.envs import AirframeParams, QuadrotorEnv
from bfc.evaluation import judge, protocol_starts
from bfc.evaluation.rotorpy_sim import (
    RotorPyQuads,
    flight_params,
    fly_condition_rotorpy,
    fly_rotorpy,
    robust_results_rotorpy,
    wind_speed_for_drag,
)
from bfc.evaluation.suites import ground_starts, horizontal_wind

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "pretrained" / "policy.pt"
HAVE_ROTORPY = all(importlib.util.find_spec(m) is not None for m in ("rotorpy", "torchdiffeq", "roma"))
needs_rotorpy = pytest.mark.skipif(not HAVE_ROTORPY, reason='RotorPy is not installed: pip install -e ".[rotorpy]"')
NOMINAL = AirframeParams()
HOVER = NOMINAL.hover_speed


def evaluate(*args, out, prelude: str = "pass"):
    """evaluate.py in a new interpreter, after `prelude` (e.g. one that hides a package)."""
    code = f"import sys, runpy; {prelude}; sys.argv = ['evaluate.py', *sys.argv[1:]]; "
    code += "runpy.run_path('evaluate.py', run_name='__main__')"
    return subprocess.run(
        [sys.executable, "-c", code, *args, f"hydra.run.dir={out}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=300,
    )


@needs_rotorpy
@pytest.mark.parametrize("airframe", ["bfc", "rotorpy"])
def test_the_shipped_policy_flies_to_the_goal_in_rotorpy(airframe):
    starts = torch.cat([protocol_starts(2, seed=0), ground_starts(2, seed=0)])  # two on the floor at once
    flights = fly_rotorpy(SHIPPED, starts, seconds=3.0, airframe=airframe)
    assert flights.shape == (4, 300)  # the policy's own 100 Hz
    pos = flights.get(("state", "position"))
    goal = torch.tensor([0.0, 0.0, 1.5])
    assert torch.equal(flights.get("odometry")[..., 0:3], pos)  # the odometry is the vehicle's state
    assert bool(flights.get("alive")[:, -1].all())
    before, after = (starts[:, 0:3] - goal).norm(dim=-1), (pos[:, -1] - goal).norm(dim=-1)
    assert bool((after < 0.5 * before).all()), (before, after)
    assert bool((pos[2:, -1, 2] > 1.0).all())  # the ground starts took off
    assert judge(flights).success.shape == (4,)


@needs_rotorpy
def test_a_classical_controller_flies_in_rotorpy_too():
    flights = fly_rotorpy("lee", protocol_starts(2, seed=0), seconds=2.0)
    assert flights.shape == (2, 500)  # the paper's 250 Hz
    pos = flights.get(("state", "position"))[:, -1]
    assert bool(flights.get("alive")[:, -1].all())
    assert bool(((pos - torch.tensor([0.0, 0.0, 1.5])).norm(dim=-1) < 0.3).all()), pos


def _bfc_response(command: torch.Tensor, body: AirframeParams, steps: int = 5) -> torch.Tensor:
    env = QuadrotorEnv(1, control_hz=100.0, start_motors="hover", num_threads=1, airframe=body)
    start = torch.zeros(1, 12, dtype=torch.float64)
    start[0, 2] = 1.5
    env.restart(torch.ones(1, dtype=torch.bool), start)
    for _ in range(steps):
        flat, _, _ = env.advance(command)
    env.close()
    return flat[0, 0:18].double()


def _rotorpy_response(command: torch.Tensor, airframe: str, body: AirframeParams, steps: int = 5) -> torch.Tensor:
    quads = RotorPyQuads(flight_params(airframe, body, body), 1, 0.01, airframe, body=body)
    start = torch.zeros(1, 12)
    start[0, 2] = 1.5
    quads.place(start, motor_speeds=body.hover_speed)
    for _ in range(steps):
        quads.step(command)
    return quads.odometry()[0].double()


def _differential(body: AirframeParams, axis: int) -> list[float]:
    """rad/s added to each motor to turn the body about `axis` only, from the rotors' positions and
    spins: roll by the +y side up, pitch by the back up, yaw by the clockwise pair up (the
    reaction moment is weak); the Hummingbird's (+-30, +-30, +-100) rad/s, scaled to the hover."""
    x, y = ([p[i] for p in body.rotor_positions] for i in (0, 1))
    size = (0.0655 if axis < 2 else 0.218) * body.hover_speed
    signs = {0: [math.copysign(1, v) if abs(v) > 1e-9 else 0 for v in y]}
    signs[1] = [-math.copysign(1, v) if abs(v) > 1e-9 else 0 for v in x]
    signs[2] = list(body.rotor_spins)
    return [size * s for s in signs[axis]]


@needs_rotorpy
@pytest.mark.parametrize("name", ["hummingbird", "crazyflie"])
@pytest.mark.parametrize("airframe", ["bfc", "rotorpy"])
@pytest.mark.parametrize("axis", [0, 1, 2], ids=["roll", "pitch", "yaw"])
def test_a_differential_command_turns_rotorpy_as_it_turns_bfc(axis, airframe, name):
    """bfc's airframe in RotorPy, and RotorPy's own vehicle of it (its Hummingbird, its Crazyflie),
    turn the way bfc's env does under the same motor commands."""
    body = airframe_params(name)
    command = torch.tensor([_differential(body, axis)]) + body.hover_speed
    ours, theirs = _bfc_response(command, body), _rotorpy_response(command, airframe, body)
    rate, angle = 12 + axis, 9 + axis  # body rate and Euler angle of that axis (bfc's odometry)
    assert abs(ours[rate]) > 0.1  # the command does turn bfc's drone
    assert torch.sign(theirs[rate]) == torch.sign(ours[rate]), (ours[12:15], theirs[12:15])
    assert torch.sign(theirs[angle]) == torch.sign(ours[angle]), (ours[9:12], theirs[9:12])
    others = [12 + a for a in range(3) if a != axis]
    assert bool((theirs[others].abs() < 0.1 * theirs[rate].abs()).all()), theirs[12:15]
    if airframe == "bfc":  # the same body and motors: the same turn, up to the motor lag's form
        assert 0.7 < float(theirs[rate] / ours[rate]) < 1.4, (ours[rate], theirs[rate])


@needs_rotorpy
def test_rotorpy_airframe_rotorpy_flies_rotorpys_own_crazyflie():
    from rotorpy.vehicles.crazyflie_params import quad_params

    body = airframe_params("crazyflie")
    params = flight_params("rotorpy", body, body)
    assert params["mass"] == quad_params["mass"] and params["Izz"] == quad_params["Izz"]  # RotorPy's own values
    heavier = flight_params("rotorpy", body, dataclasses.replace(body, body_mass=1.3 * body.body_mass))
    assert heavier["mass"] == pytest.approx(1.3 * quad_params["mass"])  # a mismatch row: the same ratio
    with pytest.raises(ValueError, match="RotorPy's own hummingbird or crazyflie"):
        flight_params("rotorpy", airframe_params("x500"), airframe_params("x500"))


@needs_rotorpy
@pytest.mark.parametrize("airframe", ["bfc", "rotorpy"])
def test_the_batched_vehicle_flies_as_rotorpys_reference_multirotor(airframe):
    """RotorPyQuads integrates with RotorPy's BatchedMultirotor; its reference `Multirotor`
    (SciPy, one vehicle per call) flies the same commands from the same tilted, spinning starts."""
    from rotorpy.vehicles.multirotor import Multirotor

    params = flight_params(airframe, NOMINAL, NOMINAL)
    starts = torch.tensor(
        [
            [0.5, -0.3, 2.0, 0.4, -0.3, 1.0, 0.5, 0.0, -0.2, 1.0, -0.5, 0.3],
            [0, 0, 2.5, -0.6, 0.2, -2.0, 0, 0, 0, 0, 0, 0],
        ]
    )
    quads = RotorPyQuads(params, 2, 0.01, airframe)
    quads.place(starts, motor_speeds=HOVER)
    reference = Multirotor(params, aero=True, integrator_kwargs={"method": "RK45", "rtol": 1e-10, "atol": 1e-12})
    states = [{k: v[i].numpy().copy() for k, v in quads.state.items()} for i in range(2)]
    g = torch.Generator().manual_seed(0)
    for _ in range(30):
        command = HOVER * (1 + 0.2 * (torch.rand(2, 4, generator=g) - 0.5))
        rp_order = command.double()[:, quads.order].numpy()
        states = [reference.step(s, {"cmd_motor_speeds": rp_order[i]}, 0.01) for i, s in enumerate(states)]
        quads.step(command)
    for i in range(2):
        np.testing.assert_allclose(quads.state["x"][i].numpy(), states[i]["x"], atol=1e-4)
        np.testing.assert_allclose(quads.state["w"][i].numpy(), states[i]["w"], atol=1e-3)
    assert float(quads.state["x"][:, 2].min()) < 2.0  # it did move


@needs_rotorpy
def test_the_wind_row_is_air_whose_drag_at_hover_is_its_force():
    params = flight_params("bfc", NOMINAL, NOMINAL)
    speed = wind_speed_for_drag(params, 1.0)
    quads = RotorPyQuads(params, 1, 0.01, "bfc", wind=[0.0, speed, 0.0])
    start = torch.zeros(1, 12)
    start[0, 2] = 1.5
    quads.place(start, motor_speeds=HOVER)
    quads.step(torch.full((1, 4), HOVER))
    accel = quads.odometry()[0, 6:9]  # the velocity difference quotient, world
    assert abs(float(accel[1]) * NOMINAL.total_mass - 1.0) < 0.05, accel
    assert abs(float(accel[0])) < 0.01


@needs_rotorpy
def test_a_robust_row_flies_in_rotorpy_its_wind_as_air_in_the_rows_direction():
    flights = fly_condition_rotorpy(SHIPPED, "wind 1 N", num_starts=2, seconds=0.5)
    air, force = flights.get("wind")[:, 0].double(), horizontal_wind(2, 1.0, seed=0)
    speed = wind_speed_for_drag(flight_params("bfc", NOMINAL, NOMINAL), 1.0)
    torch.testing.assert_close(air, force * speed, atol=1e-5, rtol=1e-5)
    protocol = SimpleNamespace(seconds=2.0, threshold=0.10, hold_seconds=1.0)
    row = robust_results_rotorpy({"bfc": SHIPPED}, ["mass +30%"], num_starts=2, protocol=protocol)["mass +30%"]["bfc"]
    assert {"success_rate", "crashes", "hover_error_m", "wall_seconds"} <= set(row) and row["crashes"] == 0


@needs_rotorpy
def test_evaluate_flies_rotorpy(tmp_path):
    args = ["sim=rotorpy", "eval.num_starts=2", "eval.seconds=2", "figures=false"]
    r = evaluate(f"policy={SHIPPED}", *args, out=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    results = json.loads((tmp_path / "results.json").read_text())
    assert results["sim"] == "rotorpy (bfc airframe)" and results["starts"] == 2


@pytest.mark.parametrize(
    "args, message",
    [
        (["sim=bullet"], "error: sim must be one of mujoco, rotorpy, got 'bullet'"),
        (["sim=rotorpy", "rotorpy_airframe=x"], "error: rotorpy_airframe must be one of bfc, rotorpy, got 'x'"),
        (["rotorpy_airframe=rotorpy"], "error: rotorpy_airframe only applies with sim=rotorpy"),
        (["sim=rotorpy", "noise.kind=ou"], "error: noise does not apply with sim=rotorpy"),
        (["sim=rotorpy", "suite=paper"], "error: sim=rotorpy flies the protocol (no suite) or suite=robust"),
    ],
)
def test_evaluate_rejects_bad_sim_keys(args, message, tmp_path):
    r = evaluate(f"policy={SHIPPED}", *args, out=tmp_path)
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert r.stderr.strip().splitlines() == [r.stderr.strip()] and r.stderr.startswith(message), r.stderr


def test_evaluate_without_rotorpy_says_how_to_install_it(tmp_path):
    r = evaluate(f"policy={SHIPPED}", "sim=rotorpy", out=tmp_path, prelude="sys.modules['rotorpy'] = None")
    assert r.returncode == 2 and "Traceback" not in r.stderr, r.stderr[-2000:]
    assert len(r.stderr.strip().splitlines()) == 1
    assert r.stderr.startswith('error: sim=rotorpy needs RotorPy: pip install -e ".[rotorpy]"'), r.stderr
    assert not (tmp_path / "results.json").exists()


@needs_rotorpy
def test_an_onnx_file_flies_like_its_policy_in_both_simulators(tmp_path):
    pytest.importorskip("onnxruntime")
    from bfc.agent.onnx import export_onnx
    from bfc.evaluation import fly

    onnx = export_onnx(SHIPPED, tmp_path / "policy.onnx")
    starts = torch.cat([protocol_starts(2, seed=0), ground_starts(1, seed=0)])
    for flown in (fly, fly_rotorpy):
        a, b = flown(SHIPPED, starts, seconds=1.5), flown(onnx, starts, seconds=1.5)
        assert a.shape == b.shape == (3, 150)  # the file's own 100 Hz
        va, vb = judge(a, 0.1, 0.5), judge(b, 0.1, 0.5)
        assert torch.equal(va.success, vb.success) and bool(va.success.any())
        gap = (a.get(("state", "position"))[:, -1] - b.get(("state", "position"))[:, -1]).abs().max()
        assert gap < 0.01, (flown.__name__, gap)  # the same controller, to float rounding
    with pytest.raises(ValueError, match="trained at 100 Hz"):
        fly(onnx, starts, seconds=1.0, control_hz=250)
    r = evaluate(
        f"policy={onnx}",
        "sim=rotorpy",
        "eval.num_starts=2",
        "eval.seconds=0.5",
        "eval.hold_seconds=0.2",
        "figures=false",
        out=tmp_path / "e",
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((tmp_path / "e" / "results.json").read_text())["starts"] == 2
