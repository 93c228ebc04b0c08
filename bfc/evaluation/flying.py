"""`fly`: any controller (a policy file, a classical controller by name, a TensorDictModule) flown
from given starts, in the env its kind needs (bfc.factory.make_flight_env), through `run_flights`.

Training never imports this module (it would bring the classical controllers and their solvers).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase

from bfc.agent import load_policy
from bfc.envs import GOAL, AirframeParams
from bfc.envs.params import as_params
from bfc.evaluation.flights import run_flights
from bfc.factory import FlightConditions, make_flight_env, trained_rate


def is_module(controller) -> bool:
    return isinstance(controller, (TensorDictModuleBase, torch.nn.Module))


def _goal_schedule(goal, dt: float):
    """`goal` as (3,) or as [(time_s, (x, y, z)), ...]: -> (first goal, [(step, goal), ...])."""
    g = list(goal)
    if len(g) == 3 and all(isinstance(v, (int, float)) for v in g):
        return torch.tensor(g, dtype=torch.float32), None
    try:
        sched = [(round(float(t) / dt), torch.tensor([float(v) for v in xyz])) for t, xyz in g]
    except (TypeError, ValueError):
        raise ValueError("goal must be (x, y, z) or a list of (time_seconds, (x, y, z)) waypoints") from None
    if not sched or sched[0][0] != 0 or any(w.shape != (3,) for _, w in sched):
        raise ValueError("a waypoint schedule must start at time 0 and give (x, y, z) for each waypoint")
    return sched[0][1], sched


PROTOCOL_HZ = 250.0  # the paper's control rate, for controllers that do not record their own


def airframe_of(controller, default: AirframeParams | None = None) -> AirframeParams:
    """The nominal airframe `controller` flies: a policy file's (or an exported model's) own; else
    `default` (a classical controller is built for it, a module flies it), the Hummingbird when None."""
    from bfc.controllers import CONTROLLERS

    path = isinstance(controller, (str, bytes)) or hasattr(controller, "__fspath__")
    if path and is_onnx_path(controller):
        from bfc.agent.onnx import read_metadata

        return AirframeParams(**read_metadata(controller)["airframe"])
    if path and str(controller) not in CONTROLLERS:
        return load_policy(controller)[0].nominal_airframe
    return default or AirframeParams()


def fly(controller, starts, goal=GOAL, flight: FlightConditions | dict | None = None, **changes) -> TensorDict:
    """Fly all `starts` (n, 12) at once towards `goal`, never resetting mid-flight, in `flight`'s
    conditions (a FlightConditions: the length, noise, mismatch, wind, latency ...; `changes`: any
    of its fields by keyword, e.g. `fly("policy.pt", starts, seconds=5, noise={"kind": "ou"})`).

    controller: a policy.pt path (flown as its PolicySpec says: its maps, its control rate, its
    nominal airframe), an exported policy.onnx (flown by onnxruntime at its control rate), a
    controller name registered in `CONTROLLERS` (built for the nominal airframe, whatever body it
    flies), or a TensorDictModule reading `"odometry"`/`"goal"` and writing `"action"` in rad/s
    (flown at `control_hz`, default 250 Hz as in the paper, on `nominal`, default the Hummingbird;
    an export's OnnxController or CController at its own rate, an OnnxController on its airframe).
    goal: (x, y, z) or waypoints [(time_s, (x, y, z)), ...].
    Returns a TensorDict (n, T); see `run_flights`.
    """
    from bfc.controllers import CONTROLLERS

    f = as_params(FlightConditions, flight, **changes)
    starts = torch.as_tensor(starts, dtype=torch.float32)
    if starts.ndim != 2 or starts.shape[1] != 12:
        raise ValueError(f"starts must have shape (n, 12), got {tuple(starts.shape)}")
    spec, name, control_hz, nominal = None, None, f.control_hz, f.nominal
    if isinstance(controller, (str, bytes)) and str(controller) in CONTROLLERS:
        name = str(controller)
    elif is_module(controller) or is_onnx_path(controller):
        if not is_module(controller):
            controller = onnx_controller(controller)[0]  # its rate is checked below, as any export's
        recorded = getattr(controller, "metadata", None)  # an export's controller flies as its file says
        if isinstance(recorded, dict) and "control_hz" in recorded:
            control_hz = trained_rate(recorded["control_hz"], control_hz, getattr(controller, "path", "this model"))
        if isinstance(recorded, dict) and "airframe" in recorded and nominal is None:
            nominal = recorded["airframe"]
    elif isinstance(controller, (str, bytes)) or hasattr(controller, "__fspath__"):
        spec, controller = load_policy(controller)
    else:
        raise ValueError(f"controller must be {controller_kinds()}, got {controller!r}")
    rate = None if spec is not None and control_hz is None else float(control_hz or PROTOCOL_HZ)
    env = make_flight_env(starts.shape[0], f, policy=spec, control_hz=rate, nominal=nominal)
    try:
        if name is not None:  # built for the nominal airframe, whatever body it flies
            controller = CONTROLLERS[name](AirframeParams(**dict(nominal or {})), env.base_env.dt)
        first, schedule = _goal_schedule(goal, env.base_env.dt)
        env.base_env.set_goal(first)
        return run_flights(env, controller, starts, round(f.seconds / env.base_env.dt), goal_schedule=schedule)
    finally:
        env.close()


def controller_kinds() -> str:
    """What `fly` and `fly_rotorpy` fly, for their error."""
    from bfc.controllers import CONTROLLERS

    return f"a policy.pt or .onnx path, one of {sorted(CONTROLLERS)} or a TensorDictModule"


def is_onnx_path(controller) -> bool:
    return (isinstance(controller, (str, bytes)) or hasattr(controller, "__fspath__")) and str(controller).endswith(
        ".onnx"
    )


def onnx_controller(path, control_hz=None):
    """An exported policy (bfc.export) as its OnnxController and the rate it was trained at."""
    from bfc.agent.onnx import OnnxController

    try:
        controller = OnnxController(path)
    except ImportError as err:  # the onnx extra: one line, as for any bad input
        raise ValueError(str(err).splitlines()[0]) from None
    return controller, trained_rate(controller.control_hz, control_hz, path)
