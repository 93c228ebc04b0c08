"""The shipped Crazyflie policy carries its airframe and flies it: in MuJoCo, exported (ONNX, C),
and in RotorPy's own Crazyflie."""

import dataclasses
import shutil

import pytest
import torch

from bfc.agent import load_policy
from bfc.config import airframe_params
from bfc.evaluation import fly, protocol_starts, success
from bfc.evaluation.suites import fly_condition, score
from tests.export_helpers import CRAZYFLIE

CF = airframe_params("crazyflie")


def test_its_file_holds_the_crazyflie_it_was_trained_on():
    spec, _ = load_policy(CRAZYFLIE)
    assert spec.nominal_airframe == CF  # every field, the layout and spins included
    assert spec.make_action_map().hover_speed == pytest.approx(CF.hover_speed)  # 1,788.6 rad/s, not 457.9
    assert spec.control_hz == 50.0  # the built-in Crazyflie's rate (conf/env/airframe/crazyflie.yaml)


def test_it_flies_the_protocol_and_takes_off_from_its_own_floor():
    flights = fly(CRAZYFLIE, protocol_starts(20, seed=0), seconds=6.0)
    assert success(flights).all()
    ground = fly_condition(CRAZYFLIE, "ground", 10, seconds=6.0)
    assert ground.get(("state", "position"))[:, 0, 2].max() < 0.02  # a 3 cm tall drone's floor
    assert score(ground)["success_rate"] == 1.0


def test_the_onnx_model_flies_its_airframe_as_the_torch_policy(tmp_path):
    pytest.importorskip("onnxruntime")
    from bfc.export import export_onnx, read_metadata

    path = export_onnx(CRAZYFLIE, tmp_path / "crazyflie.onnx")
    meta = read_metadata(path)
    assert meta["airframe"]["name"] == "crazyflie" and meta["motor_order"].startswith("0 front-left (+x +y) CW")
    starts = protocol_starts(6, seed=0)
    by_torch, by_onnx = (
        fly(CRAZYFLIE, starts, seconds=4.0),
        fly(path, starts, seconds=4.0),
    )  # the file says its airframe
    position = (by_onnx.get(("state", "position")) - by_torch.get(("state", "position"))).abs().max()
    assert position < 1e-3


@pytest.mark.skipif(shutil.which("cc") is None, reason="no system C compiler `cc` on the PATH (apt-get install gcc)")
def test_the_c_header_flies_its_airframe_as_the_torch_policy(tmp_path):
    from bfc.export import CController, export_c

    header = export_c(CRAZYFLIE, tmp_path / "policy.h")
    assert "motor order 0 front-left (+x +y) CW" in header.read_text()
    controller = CController(header)
    assert controller.hover_speed == pytest.approx(CF.hover_speed, rel=1e-6)
    starts = protocol_starts(6, seed=0)
    by_torch = fly(CRAZYFLIE, starts, seconds=4.0)
    by_c = fly(controller, starts, seconds=4.0, control_hz=controller.control_hz, nominal=dataclasses.asdict(CF))
    position = (by_c.get(("state", "position")) - by_torch.get(("state", "position"))).abs().max()
    assert position < 1e-3


def test_it_flies_rotorpys_own_crazyflie():
    pytest.importorskip("rotorpy")
    from bfc.evaluation.rotorpy_sim import fly_rotorpy

    flights = fly_rotorpy(CRAZYFLIE, protocol_starts(4, seed=0), seconds=5.0, airframe="rotorpy")
    assert bool(flights.get("alive")[:, -1].all())
    end = flights.get(("state", "position"))[:, -1]
    assert bool(((end - torch.tensor([0.0, 0.0, 1.5])).norm(dim=-1) < 0.1).all()), end
