"""suite=hardware: the throw's starts, each row's construction, latency and a biased estimate in
`fly`, and evaluate.py's hardware suite and its bad inputs."""

import json
import math

import pytest
import torch
from tensordict.nn import TensorDictModuleBase

from bfc import keys
from bfc.envs import AirframeParams
from bfc.envs.rotations import euler_to_quat
from bfc.evaluation import fly, protocol_starts
from bfc.evaluation.metrics import tilt_degrees
from bfc.evaluation.suites import ESTIMATOR_NOISE, HARDWARE, SUITES, condition, fly_condition, throw_starts
from tests.evaluation.scripts import SHIPPED, evaluate

DEG = math.pi / 180


def test_throw_starts_fly_at_5_m_s_at_any_attitude_spinning_up_to_5_rad_s():
    s = throw_starts(2000, seed=0)
    speed = s[:, 6:9].norm(dim=-1)
    torch.testing.assert_close(speed, torch.full((2000,), 5.0), rtol=1e-5, atol=1e-5)
    elevation = torch.asin(s[:, 8] / speed) / DEG
    assert elevation.min() >= -20 - 1e-3 and elevation.max() <= 45 + 1e-3
    assert elevation.min() < -18 and elevation.max() > 43
    heading = torch.atan2(s[:, 7], s[:, 6])
    assert heading.min() < -3.0 and heading.max() > 3.0  # every horizontal direction
    spin = s[:, 9:12].norm(dim=-1)
    assert spin.max() <= 5.0 + 1e-5 and spin.max() > 4.9 and spin.mean() > 2.0
    upside_down = (tilt_degrees(euler_to_quat(s[:, 3:6].double())) > 90).float().mean().item()
    assert 0.45 < upside_down < 0.55
    assert (s[:, 2] >= 2.0).all() and (s[:, 2] <= 4.0).all() and s[:, 0:2].abs().max() <= 2.0
    assert torch.equal(throw_starts(10, 1), throw_starts(10, 1)) and not torch.equal(throw_starts(10, 0), s[:10])


def test_each_hardware_row_says_what_it_changes():
    assert set(SUITES) == {"robust", "hardware"} and not set(SUITES["robust"]) & set(HARDWARE)
    delays = {n: (c.observation_delay, c.action_delay) for n, c in HARDWARE.items() if "latency" in n}
    assert delays == {
        "observation latency 10 ms": (0.010, 0.0),
        "observation latency 20 ms": (0.020, 0.0),
        "observation latency 30 ms": (0.030, 0.0),
        "observation latency 50 ms": (0.050, 0.0),
        "actuation latency 10 ms": (0.0, 0.010),
        "actuation latency 20 ms": (0.0, 0.020),
    }
    noisy = condition("estimator noise, gyro bias")
    assert noisy.noise is ESTIMATOR_NOISE and noisy.starts == "protocol"
    std, bias = torch.tensor(ESTIMATOR_NOISE["std"]), torch.tensor(ESTIMATOR_NOISE["bias"])
    assert std[0:3].eq(0.02).all() and std[9:12].sub(DEG).abs().max() < 1e-9 and std[12:15].eq(0.03).all()
    assert bias[12:15].eq(0.02).all() and bias[:12].eq(0).all() and bias[15:].eq(0).all()
    throw = condition("throw 5 m/s, any attitude")
    assert throw.starts == "throw" and throw.start_motors == "hover"
    with pytest.raises(ValueError, match="unknown condition"):
        condition("moon gravity")


def test_late_odometry_reaches_the_controller_whole_steps_late():
    seen = []

    class Recorder(TensorDictModuleBase):
        """A controller that commands a little more than hover and records the odometry it is given."""

        def __init__(self):
            super().__init__()
            self.in_keys, self.out_keys = [keys.ODOMETRY, keys.GOAL], [keys.ACTION]

        def forward(self, td):
            seen.append(td.get(keys.ODOMETRY).clone())
            return td.set(keys.ACTION, torch.full((td.shape[0], 4), AirframeParams().hover_speed * 1.1))

    starts = protocol_starts(3, seed=0)
    runs = {}
    for delay in (0.0, 0.012):  # 12 ms at 250 Hz: 3 steps (rounded down from 3.0)
        seen.clear()
        flights = fly(Recorder(), starts, seconds=0.1, control_hz=250, observation_delay=delay)
        runs[delay] = (torch.stack(seen), flights)
    now, late = runs[0.0][0], runs[0.012][0]
    for t in range(len(now)):
        assert torch.equal(late[t], now[max(0, t - 3)])
    # the flown states are the same (the commands did not depend on what was seen): only the view is late
    assert torch.equal(runs[0.0][1].get(keys.POSITION), runs[0.012][1].get(keys.POSITION))


def test_a_biased_estimate_keeps_one_offset_per_flight():
    starts = protocol_starts(64, seed=0)
    flights = fly(SHIPPED, starts, seconds=0.5, noise={"kind": "gaussian", "std": 0.0, "bias": 0.05})
    offset = flights.get(keys.ODOMETRY)[..., 0:3] - flights.get(keys.POSITION)
    assert offset.std(1).max() < 1e-5  # constant within a flight
    spread = offset[:, 0].std(0)  # (3,): N(0, 0.05^2) across flights, per axis
    assert bool(((spread > 0.035) & (spread < 0.065)).all()), spread


def test_the_throw_is_released_with_the_motors_at_hover():
    flights = fly_condition("lee", "throw 5 m/s, any attitude", num_starts=4, seconds=0.02)
    first = flights.get(keys.MOTOR_SPEEDS)[:, 0]
    hover = AirframeParams().hover_speed
    assert (first - hover).abs().max() < 0.35 * hover  # one 4 ms step from hover, not spun up from rest


def test_evaluate_flies_the_hardware_suite_and_rejects_what_it_cannot(tmp_path):
    r = evaluate(
        "suite=hardware",
        f"policy={SHIPPED}",
        "baselines=[lee]",
        "eval.num_starts=2",
        "eval.seconds=0.6",
        "eval.hold_seconds=0.2",
        out=tmp_path,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    results = json.loads((tmp_path / "hardware.json").read_text())
    assert list(results) == list(HARDWARE) and set(results["throw 5 m/s, any attitude"]) == {"bfc", "lee"}
    assert (tmp_path / "hardware.md").read_text().startswith("# What hardware brings")
    assert (tmp_path / "hardware.png").stat().st_size > 0  # drawn even where no flight succeeded
    r = evaluate("suite=hardware", f"policy={SHIPPED}", "sim=rotorpy", out=tmp_path / "bad")
    line = "error: sim=rotorpy flies the protocol (no suite) or suite=robust; suite=hardware flies MuJoCo only"
    assert r.returncode == 2 and r.stderr.strip() == line, r.stderr
