"""ONNX export (bfc/export.py): parity with the torch policy, a protocol flight, the CLI."""

import subprocess
import sys

import numpy as np
import pytest
import torch
from tensordict import TensorDict

ort = pytest.importorskip("onnxruntime")
pytest.importorskip("onnx")

from bfc.agent import POLICY_FORMAT, PolicySpec, load_policy, save_policy  # noqa: E402
from bfc.envs.params import AirframeParams  # noqa: E402
from bfc.export import OnnxController, export_onnx, main, read_metadata  # noqa: E402
from tests.export_helpers import (  # noqa: E402
    CRAZYFLIE,
    PRETRAINED,
    ROOT,
    SCALED,
    TOLERANCE,
    X500,
    hover_speed_difference,
    parity_rows,
    random_inputs,
    tiny_policy,
    torch_reference,
)


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    d = tmp_path_factory.mktemp("onnx")
    tiny = tiny_policy(d / "tiny.pt")
    normalized = tiny_policy(d / "normalized.pt", normalize=True)
    scaled = tiny_policy(d / "scaled.pt", scales=SCALED)
    return {
        "pretrained": (PRETRAINED, export_onnx(PRETRAINED, d / "pretrained.onnx")),
        "crazyflie": (CRAZYFLIE, export_onnx(CRAZYFLIE, d / "crazyflie.onnx")),
        "x500": (X500, export_onnx(X500, d / "x500.onnx")),
        "tiny": (tiny, export_onnx(tiny, d / "tiny.onnx")),
        "normalized": (normalized, export_onnx(normalized, d / "normalized.onnx")),
        "scaled": (scaled, export_onnx(scaled, d / "scaled.onnx")),
    }


@pytest.mark.parametrize("name", ["pretrained", "crazyflie", "x500", "tiny", "normalized", "scaled"])
def test_onnx_matches_the_torch_policy(models, name):
    policy_path, onnx_path = models[name]
    spec, _ = load_policy(policy_path)
    hover, top = spec.nominal_airframe.hover_speed, spec.nominal_airframe.max_rotor_speed
    # 1000 rows over the protocol's states and far beyond, and 1000 near hover at the goal (where
    # a trained policy's commands are mostly inside its range); a history policy's older commands
    odometry, goal, previous, integral, history = parity_rows(spec)
    k = spec.command_history
    expected, _ = torch_reference(policy_path, odometry, goal, previous, integral, history)
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    inputs, outputs = ["odometry", "goal", "previous_motor_speeds"], ["motor_speeds"]
    feeds = {"odometry": odometry.numpy(), "goal": goal.numpy(), "previous_motor_speeds": previous.numpy()}
    if spec.position_integral:
        inputs.append("position_error_integral")
        outputs.append("next_position_error_integral")
        feeds["position_error_integral"] = integral.numpy()
    if k:
        inputs.append("motor_speed_history")
        outputs.append("next_motor_speed_history")
        feeds["motor_speed_history"] = history.numpy()
    assert [i.name for i in session.get_inputs()] == inputs
    assert [o.name for o in session.get_outputs()] == outputs
    got = session.run(None, feeds)[0]
    assert got.shape == (2000, 4) and got.dtype == np.float32
    # in the policy's action units: near zero speed the thrust map's square root turns float32
    # rounding into up to 0.013 rad/s (seen with a history policy's commands near 0)
    to_action = spec.make_action_map().to_action
    diff = float((to_action(torch.from_numpy(got)) - to_action(expected)).abs().max())
    assert diff <= TOLERANCE, f"max |onnx - torch| = {diff:.2e} in action units"
    # and in hover speeds, as for every policy (a history policy with the hover history a reset gives)
    got_rad, expected_rad = got, expected
    if k:
        at_hover = torch.full((2000, k, 4), hover)
        expected_rad, _ = torch_reference(policy_path, odometry, goal, previous, integral, at_hover)
        got_rad = session.run(None, {**feeds, "motor_speed_history": at_hover.numpy()})[0]
    hover_diff = hover_speed_difference(got_rad, expected_rad, spec)  # away from the square root's 0
    assert hover_diff <= TOLERANCE, f"max |onnx - torch| = {hover_diff:.2e} hover speeds"
    # the comparison is not all saturated motors: most commands lie strictly inside (0, max)
    inside = (expected > 0) & (expected < top)
    assert inside.float().mean() > 0.5
    assert got.min() >= 0.0 and got.max() <= top
    # dynamic batch: one row gives the same numbers
    one = session.run(None, {k: v[:1] for k, v in feeds.items()})[0]
    np.testing.assert_allclose(one, got[:1], rtol=0, atol=TOLERANCE * hover)


def test_metadata_records_how_to_fly(models, tmp_path):
    meta = read_metadata(models["pretrained"][1])
    assert meta["control_hz"] == 100.0 and meta["action_map"] == "thrust"
    assert meta["position_integral"] and meta["observation"] == "heading"  # the default since the robust extras
    assert meta["hover_speed"] == pytest.approx(AirframeParams().hover_speed)
    assert meta["max_rotor_speed"] == 838.0 and meta["policy_format"] == POLICY_FORMAT
    meta = read_metadata(models["tiny"][1])
    assert meta["control_hz"] == 250.0 and meta["action_map"] == "speed" and meta["include_acceleration"]
    assert not meta["position_integral"]
    assert meta["hover_speed"] == pytest.approx(AirframeParams(body_mass=0.8).hover_speed)
    assert meta["max_rotor_speed"] == 900.0


def test_controller_feeds_back_its_command_and_resets(models):
    policy_path, onnx_path = models["tiny"]
    controller = OnnxController(onnx_path)
    hover, top = controller.hover_speed, controller.max_rotor_speed
    odometry, goal, _ = random_inputs(5, hover, top, seed=1)

    def call(odom, step_count=None):
        td = TensorDict({"odometry": odom, "goal": goal[: len(odom)]}, batch_size=[len(odom)])
        if step_count is not None:
            td.set("step_count", step_count)
        return controller(td).get("action")

    first = call(odometry)
    expected, _ = torch_reference(policy_path, odometry, goal, torch.full((5, 4), hover))
    torch.testing.assert_close(first, expected, rtol=0, atol=TOLERANCE * hover)
    second = call(odometry)  # now the previous command is `first`
    expected, _ = torch_reference(policy_path, odometry, goal, first)
    torch.testing.assert_close(second, expected, rtol=0, atol=TOLERANCE * hover)
    controller.reset()
    torch.testing.assert_close(call(odometry), first)
    call(odometry[:3])  # another batch size: a new flight from hover
    torch.testing.assert_close(call(odometry)[:3], first[:3])  # and back: again from hover
    # per-env resets, as an auto-resetting runner with a StepCounter reports them
    call(odometry)
    mixed = call(odometry, step_count=torch.tensor([[0], [3], [0], [3], [3]]))
    torch.testing.assert_close(mixed[[0, 2]], first[[0, 2]])
    assert not torch.allclose(mixed[[1, 3, 4]], first[[1, 3, 4]])


def test_protocol_flight_matches_the_torch_policy(models):
    from bfc.evaluation import fly, protocol_starts, success

    starts = protocol_starts(20, seed=0)
    controller = OnnxController(models["pretrained"][1])
    by_torch = fly(str(PRETRAINED), starts, seconds=10.0)
    by_onnx = fly(controller, starts, seconds=10.0, control_hz=controller.control_hz)
    assert by_onnx.shape == by_torch.shape  # same rate: 1000 steps at 100 Hz
    assert success(by_onnx).tolist() == success(by_torch).tolist()
    assert success(by_onnx).all()
    position = (by_onnx.get(("state", "position")) - by_torch.get(("state", "position"))).abs().max()
    assert position < 1e-3


def test_an_onnx_controller_flies_its_own_airframe_and_rate(models):
    """Handed over as an object, an export flies as its file says: the Crazyflie's body at 50 Hz,
    not the Hummingbird's at the paper's 250 Hz (a wrapper with no metadata says so itself)."""
    from bfc.evaluation import fly, protocol_starts, success

    starts = protocol_starts(10, seed=1)
    policy, onnx = models["crazyflie"]
    by_torch = fly(str(policy), starts, seconds=4.0)
    by_onnx = fly(OnnxController(onnx), starts, seconds=4.0)
    assert by_onnx.shape == by_torch.shape == (10, 200)  # 50 Hz
    assert success(by_onnx).tolist() == success(by_torch).tolist()
    position = (by_onnx.get(("state", "position")) - by_torch.get(("state", "position"))).abs().max()
    assert position < 1e-3
    assert fly(str(onnx), starts, seconds=1.0).shape == (10, 50)  # its path flies as its object does
    for controller in (OnnxController(onnx), str(onnx)):
        with pytest.raises(ValueError, match="trained at 50 Hz"):
            fly(controller, starts, seconds=1.0, control_hz=100.0)


def test_cli_writes_a_model_and_fails_cleanly(tmp_path, capsys):
    out = tmp_path / "sub" / "policy.onnx"
    assert main([str(PRETRAINED), str(out)]) == 0
    assert out.is_file() and "100 Hz" in capsys.readouterr().out
    assert main([str(PRETRAINED), str(tmp_path)]) == 2  # a directory is no output path
    assert capsys.readouterr().err.count("\n") == 1
    missing = subprocess.run(
        [sys.executable, "-m", "bfc.export", str(tmp_path / "nope.pt"), str(tmp_path / "x.onnx")],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert missing.returncode == 2
    lines = missing.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: no policy file at"), missing.stderr
    assert not (tmp_path / "x.onnx").exists()


def test_integral_policy_exports_its_state_and_flies_as_the_env_does(tmp_path):
    """A policy with `model.position_integral`: the graph takes and returns the integral, and the
    ONNX controller, feeding it back, flies the same flight as the torch policy in the env."""
    from bfc.evaluation import fly

    spec = PolicySpec(position_integral=True, hidden=(16,), activation="tanh", control_hz=100.0)
    torch.manual_seed(1)
    net = spec.make_net()
    with torch.no_grad():
        for p in net.mlp.parameters():
            p.normal_(0.0, 0.1)
        net.mlp[-1].weight[:, 22:25].normal_(0.0, 2.0)  # the integral inputs matter
    save_policy(tmp_path / "integral.pt", spec, net)
    onnx_path = export_onnx(tmp_path / "integral.pt", tmp_path / "integral.onnx")
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()] == [
        "odometry",
        "goal",
        "previous_motor_speeds",
        "position_error_integral",
    ]
    assert [o.name for o in session.get_outputs()] == ["motor_speeds", "next_position_error_integral"]
    controller = OnnxController(onnx_path)
    assert controller.metadata["position_integral"]
    # near the goal (inside the integration radius), hovering: the integral grows and is used
    starts = torch.zeros(8, 12)
    starts[:, 0:3] = torch.tensor([0.0, 0.0, 1.5]) + 0.1 * torch.randn(8, 3)
    by_torch = fly(str(tmp_path / "integral.pt"), starts, seconds=0.3)
    by_onnx = fly(controller, starts, seconds=0.3, control_hz=100.0)
    torch.testing.assert_close(
        by_onnx.get("action"), by_torch.get("action"), rtol=0, atol=1e-5 * controller.hover_speed
    )
    assert controller.integral.shape == (8, 3) and np.abs(controller.integral).max() > 1e-3
