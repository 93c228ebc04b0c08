"""A policy with `model.command_history`: the observation shifts its older commands in step by
step and forgets them at a reset, and both exports (ONNX, C) take and return that history, so
that fed back they fly the flight the torch policy flies in the env."""

import shutil

import numpy as np
import pytest
import torch

from bfc.agent import PolicySpec, save_policy
from bfc.transforms import PolicyObservation

K = 3


def test_the_history_shifts_in_the_previous_action_and_restarts_at_hover():
    obs_map = PolicyObservation(3, 800.0, command_history=K)
    odometry, goal = torch.zeros(3, 18), torch.zeros(3, 3)
    assert obs_map.observe_restart(torch.ones(3, dtype=torch.bool), odometry, goal).shape == (3, 22 + 4 * K)
    actions = []
    for i in range(4):
        command = torch.full((3, 4), 800.0 * (1 + 0.1 * (i + 1)))
        obs = obs_map.observe_step(command, odometry, goal)
        actions.append(command[0, 0] / 800.0 - 1)
    # newest first: the previous action at 18:22, then the three before it
    expected = torch.stack([actions[3], actions[2], actions[1], actions[0]]).repeat_interleave(4)
    torch.testing.assert_close(obs[0, 18:], expected)
    obs = obs_map.observe_restart(torch.tensor([True, False, False]), odometry, goal)
    assert (obs[0, 18:] == 0).all() and (obs[1, 18:] == obs[2, 18:]).all() and obs[1, 18:].abs().min() > 0


def test_bad_history_is_one_line():
    for bad in (-1, 1.5, True, 51):
        with pytest.raises(ValueError, match="model.command_history"):
            PolicySpec(command_history=bad)
    with pytest.raises(ValueError, match="model.observation=odometry"):
        PolicySpec(observation="odometry", command_history=2)


@pytest.fixture(scope="module")
def history_policy(tmp_path_factory):
    spec = PolicySpec(position_integral=True, command_history=K, hidden=(16,), activation="tanh", control_hz=100.0)
    torch.manual_seed(1)
    net = spec.make_net()
    with torch.no_grad():
        for p in net.mlp.parameters():
            p.normal_(0.0, 0.1)
        net.mlp[0].weight[:, 25:].normal_(0.0, 0.5)  # the history inputs matter
    path = tmp_path_factory.mktemp("history") / "history.pt"
    save_policy(path, spec, net)
    return path


def _fly_both(controller, policy_path):
    from bfc.evaluation import fly

    torch.manual_seed(0)
    starts = torch.zeros(8, 12)
    starts[:, 0:3] = torch.tensor([0.0, 0.0, 1.5]) + 0.3 * torch.randn(8, 3)
    starts[:, 3:6] = 0.5 * torch.randn(8, 3)
    by_torch = fly(str(policy_path), starts, seconds=0.3)
    by_export = fly(controller, starts, seconds=0.3, control_hz=100.0)
    actions = by_torch.get("action")
    assert actions.std(1).mean() > 1.0  # the commands change from step to step: the history is not all hover
    torch.testing.assert_close(by_export.get("action"), actions, rtol=0, atol=1e-5 * controller.hover_speed)
    assert controller.history.shape == (8, K, 4)


def test_onnx_takes_and_returns_the_history_and_flies_as_the_env_does(tmp_path, history_policy):
    ort = pytest.importorskip("onnxruntime")
    from bfc.export import OnnxController, export_onnx, read_metadata

    onnx_path = export_onnx(history_policy, tmp_path / "history.onnx")
    session = ort.InferenceSession(str(onnx_path), providers=["CPUExecutionProvider"])
    assert [i.name for i in session.get_inputs()][3:] == ["position_error_integral", "motor_speed_history"]
    assert [o.name for o in session.get_outputs()] == [
        "motor_speeds",
        "next_position_error_integral",
        "next_motor_speed_history",
    ]
    assert read_metadata(onnx_path)["command_history"] == K
    # the next history is the previous command, then the history's first K - 1 (newest first)
    n, hover = 5, 700.0
    previous = np.full((n, 4), hover, np.float32) + np.arange(4, dtype=np.float32)
    history = np.random.default_rng(0).uniform(300, 800, (n, K, 4)).astype(np.float32)
    feeds = {
        "odometry": np.zeros((n, 18), np.float32),
        "goal": np.zeros((n, 3), np.float32),
        "previous_motor_speeds": previous,
        "position_error_integral": np.zeros((n, 3), np.float32),
        "motor_speed_history": history,
    }
    _, _, next_history = session.run(None, feeds)
    np.testing.assert_array_equal(next_history, np.concatenate([previous[:, None], history[:, :-1]], 1))
    _fly_both(OnnxController(onnx_path), history_policy)


@pytest.mark.skipif(shutil.which("cc") is None, reason="no system C compiler `cc` on the PATH")
def test_c_header_takes_and_returns_the_history_and_flies_as_the_env_does(tmp_path, history_policy):
    from bfc.export import CController, export_c

    header = export_c(history_policy, tmp_path / "policy.h")
    text = header.read_text()
    assert f"#define BFC_POLICY_COMMAND_HISTORY {K} " in text and "float history[3][4];" in text
    controller = CController(header)
    assert controller.metadata["command_history"] == K
    _fly_both(controller, history_policy)
