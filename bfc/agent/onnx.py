"""The ONNX export of a policy file, and `OnnxController` to fly the exported model.

The graph is the deterministic actor (the Gaussian mean, no sampling) with the observation and
action maps inside it, so a deployer feeds it raw sensor numbers and gets motor speeds:

    inputs   odometry               (N, 18) float32, the env's odometry layout (bfc/keys.py)
             goal                   (N, 3)  float32, m, world frame
             previous_motor_speeds  (N, 4)  float32, rad/s: the command the graph output at the
                                            previous control step; the hover speed after a reset
             position_error_integral (N, 3) float32, m s, world frame: only for policies trained
                                            with `model.position_integral`; the graph's own
                                            `next_position_error_integral` of the previous step,
                                            zeros after a reset
             motor_speed_history    (N, k, 4) float32, rad/s: only for policies trained with
                                            `model.command_history=k`: the k commands before
                                            previous_motor_speeds, newest first (the graph's own
                                            `next_motor_speed_history`), the hover speed after a reset
    output   motor_speeds           (N, 4)  float32, rad/s, clipped to [0, max_rotor_speed]
             next_position_error_integral (N, 3): with the integral input only
             next_motor_speed_history (N, k, 4): with the history input only

The batch axis N is dynamic. The model's metadata_props record the control rate (`control_hz`),
`hover_speed`, `max_rotor_speed`, `action_map` and the policy format; see docs/export.md.
Everything comes from the file's PolicySpec, and the maths is not re-written here: the module
calls `PolicyObservation.build` and `MotorSpeedAction.to_action` / `to_command`, the code the env
runs in training and evaluation. Needs the `onnx` extra: pip install -e ".[onnx]".
"""

from __future__ import annotations

import dataclasses
import io
import json
import warnings
from pathlib import Path

import torch
from torch import nn

from bfc.agent.actor import GaussianActor
from bfc.agent.atomic import atomic_write, check_output_path
from bfc.agent.fed_back import FedBackController
from bfc.agent.policy_file import POLICY_FORMAT, load_policy
from bfc.agent.spec import PolicySpec
from bfc.transforms import MotorSpeedAction, PolicyObservation

ONNX_FORMAT = "bfc-onnx-v1"
INPUTS = ("odometry", "goal", "previous_motor_speeds")
OUTPUT = "motor_speeds"
INTEGRAL_INPUT, INTEGRAL_OUTPUT = "position_error_integral", "next_position_error_integral"
HISTORY_INPUT, HISTORY_OUTPUT = "motor_speed_history", "next_motor_speed_history"
ODOMETRY_LAYOUT = (
    "0:3 position (m, world), 3:6 linear velocity (m/s, world), 6:9 linear acceleration (m/s^2, world), "
    "9:12 roll, pitch, yaw (rad, ZYX), 12:15 angular velocity (rad/s, body), "
    "15:18 angular acceleration (rad/s^2, body)"
)
_INSTALL_HINT = 'ONNX export needs the onnx extra: pip install -e ".[onnx]"'


class PolicyExportModule(nn.Module):
    """(odometry, goal, previous_motor_speeds[, integral][, history]) -> motor_speeds (rad/s)
    [, next integral][, next history]: the deterministic actor with the env's observation map
    before it and its action map and motor clip after it."""

    def __init__(self, net: GaussianActor, observation: PolicyObservation, action: MotorSpeedAction):
        super().__init__()
        self.net = net
        # The maps' methods, not the transforms: only the network's weights belong in the graph
        # (a transform's buffers and extra state, such as a generator, do not).
        self.build_observation = observation.build
        self.integrate = observation.integrate if observation.position_integral else None
        self.command_history = observation.command_history
        self.shift = observation.shift
        self.to_action = action.to_action
        self.to_command = action.to_command
        self.max_speed = action.max_speed

    def forward(
        self,
        odometry: torch.Tensor,
        goal: torch.Tensor,
        previous_motor_speeds: torch.Tensor,
        *state: torch.Tensor,
    ):
        # exactly what PolicyObservation._step keeps as the previous action (and integral, history)
        state = list(state)
        last_action = self.to_action(previous_motor_speeds).clamp(-1, 1)
        integral = history = None
        if self.integrate is not None:
            integral = self.integrate(state.pop(0), odometry, goal)
        if self.command_history:
            speeds_before = state.pop(0)
            history = self.to_action(speeds_before).clamp(-1, 1)
        loc = self.net.mean(self.build_observation(odometry, goal, last_action, integral, history))
        speeds = self.to_command(loc).clamp(0.0, self.max_speed)  # the env's clip (QuadrotorEnv._step)
        outputs = [speeds] + ([integral] if integral is not None else [])
        if history is not None:
            outputs.append(self.shift(speeds_before, previous_motor_speeds))
        return outputs[0] if len(outputs) == 1 else tuple(outputs)


def export_module(policy_path) -> tuple[PolicyExportModule, PolicySpec]:
    """(the torch module the ONNX graph is traced from, the file's spec)."""
    spec, net = load_policy(policy_path)
    module = PolicyExportModule(net, spec.make_observation_map(1), spec.make_action_map()).eval()
    return module, spec


def _import_onnx():
    try:
        import onnx
    except ImportError as err:
        raise ImportError(f"{_INSTALL_HINT} ({err})") from None
    return onnx


def export_onnx(policy_path, onnx_path, opset: int | None = None) -> Path:
    """Write the deterministic policy of `policy_path` (a policy.pt) as an ONNX model at `onnx_path`.

    opset: the ONNX opset (None: the exporter's default, 20 with torch 2.13). Uses torch's
    TorchScript exporter (`dynamo=False`): it needs no onnxscript and exports in 0.2 s.
    Raises FileNotFoundError / ValueError for a missing or foreign policy file and OSError when
    `onnx_path` cannot be written. Returns the path written (written atomically).
    """
    onnx = _import_onnx()
    onnx_path = Path(onnx_path)
    check_output_path(onnx_path, "policy.onnx")
    if opset is not None and (not isinstance(opset, int) or opset < 11):
        raise ValueError(f"opset must be an int >= 11 (Clip with bounds as inputs), got {opset!r}")
    module, spec = export_module(policy_path)
    airframe = spec.nominal_airframe
    n = 2  # any batch size: the batch axis is exported as dynamic
    example = (torch.zeros(n, 18), torch.zeros(n, 3), torch.full((n, 4), airframe.hover_speed))
    inputs, outputs = list(INPUTS), [OUTPUT]
    if spec.position_integral:
        example += (torch.zeros(n, 3),)
        inputs.append(INTEGRAL_INPUT)
        outputs.append(INTEGRAL_OUTPUT)
    if spec.command_history:
        example += (torch.full((n, spec.command_history, 4), airframe.hover_speed),)
        inputs.append(HISTORY_INPUT)
        outputs.append(HISTORY_OUTPUT)
    buffer = io.BytesIO()
    with warnings.catch_warnings():  # the TorchScript exporter is deprecated in favour of dynamo (onnxscript)
        warnings.simplefilter("ignore")
        torch.onnx.export(
            module,
            example,
            buffer,
            input_names=inputs,
            output_names=outputs,
            dynamic_axes={name: {0: "batch"} for name in (*inputs, *outputs)},
            opset_version=opset,
            dynamo=False,
        )
    model = onnx.load_from_string(buffer.getvalue())
    model.producer_name = "bfc"
    model.doc_string = (
        "bfc deterministic quadrotor policy: (odometry (N,18), goal (N,3) m, previous_motor_speeds (N,4) rad/s) "
        "-> motor_speeds (N,4) rad/s in [0, max_rotor_speed]. Run it at control_hz; feed back its own output "
        "as previous_motor_speeds, hover_speed after a reset"
        + (
            "; feed back next_position_error_integral as position_error_integral, zeros after a reset"
            if spec.position_integral
            else ""
        )
        + (
            "; feed back next_motor_speed_history as motor_speed_history, hover_speed after a reset"
            if spec.command_history
            else ""
        )
        + ". See docs/export.md."
    )
    metadata = {
        "bfc_onnx_format": ONNX_FORMAT,
        "policy_format": POLICY_FORMAT,
        "control_hz": repr(spec.control_hz),
        "hover_speed": repr(airframe.hover_speed),
        "max_rotor_speed": repr(airframe.max_rotor_speed),
        "action_map": spec.action_map,
        "include_acceleration": str(spec.include_acceleration).lower(),
        "position_integral": str(spec.position_integral).lower(),
        "command_history": str(spec.command_history),
        "observation": spec.observation,
        "odometry_layout": ODOMETRY_LAYOUT,
        "motor_order": airframe.motor_order(),
        "airframe": json.dumps(dataclasses.asdict(airframe)),
        "source": Path(policy_path).name,
    }
    for key, value in metadata.items():
        entry = model.metadata_props.add()
        entry.key, entry.value = key, value
    onnx.checker.check_model(model)
    return atomic_write(onnx_path, lambda tmp: onnx.save(model, tmp), "the ONNX model")


def read_metadata(onnx_path) -> dict:
    """The bfc metadata of an exported model, with numbers as floats and flags as bools."""
    onnx = _import_onnx()
    model = onnx.load(str(onnx_path), load_external_data=False)
    return _parse_metadata({p.key: p.value for p in model.metadata_props}, onnx_path)


def _parse_metadata(meta: dict, onnx_path) -> dict:
    if meta.get("bfc_onnx_format") != ONNX_FORMAT:
        raise ValueError(f"{onnx_path} is not a bfc ONNX policy (expected bfc_onnx_format {ONNX_FORMAT!r})")
    out = dict(meta)
    for key in ("control_hz", "hover_speed", "max_rotor_speed"):
        out[key] = float(meta[key])
    out["include_acceleration"] = meta.get("include_acceleration") == "true"
    out["position_integral"] = meta.get("position_integral") == "true"
    out["command_history"] = int(meta.get("command_history", "0"))
    out["airframe"] = json.loads(meta["airframe"]) if "airframe" in meta else {}  # older exports: the Hummingbird
    return out


class OnnxController(FedBackController):
    """Flies an exported policy with onnxruntime (the state it feeds back: `FedBackController`).

    `fly(OnnxController(path), starts, control_hz=controller.control_hz)` flies it as trained.
    threads: onnxruntime intra-op threads (1: the model is tiny, and MuJoCo owns the cores).
    """

    def __init__(self, onnx_path, threads: int = 1):
        super().__init__()
        try:
            import onnxruntime as ort
        except ImportError as err:
            raise ImportError(f"{_INSTALL_HINT} ({err})") from None
        options = ort.SessionOptions()
        options.intra_op_num_threads = int(threads)
        options.inter_op_num_threads = 1
        self.path = Path(onnx_path)
        if not self.path.is_file():
            raise FileNotFoundError(f"no ONNX model at {self.path}: write one with python -m bfc.export")
        self.session = ort.InferenceSession(str(self.path), options, providers=["CPUExecutionProvider"])
        self.metadata = _parse_metadata(self.session.get_modelmeta().custom_metadata_map, self.path)
        self.control_hz = self.metadata["control_hz"]
        self.hover_speed = self.metadata["hover_speed"]
        self.max_rotor_speed = self.metadata["max_rotor_speed"]
        self.command_history = self.metadata["command_history"]

    def step(self, odometry, goal, previous, integral, history):
        feeds = {"odometry": odometry, "goal": goal, "previous_motor_speeds": previous}
        outputs = [OUTPUT]
        if self.metadata["position_integral"]:
            feeds[INTEGRAL_INPUT] = integral
            outputs.append(INTEGRAL_OUTPUT)
        if self.command_history:
            feeds[HISTORY_INPUT] = history
        speeds, *rest = self.session.run(outputs, feeds)
        return speeds, (rest[0] if rest else None)
