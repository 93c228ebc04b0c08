"""bfc's policies (and classical controllers) flown in RotorPy, a second simulator.

Why: a policy judged only in the simulator it learned in may have learned that simulator. RotorPy
(Folk et al., `pip install -e ".[rotorpy]"`) integrates its own multirotor model, with
aerodynamics bfc's MuJoCo env lacks (parasitic drag, induced inflow, translational lift), so the
same starts flown there under the same judge test the policy in another world.

How (docs/evaluation.md, "Another simulator: RotorPy"):
- RotorPy's `BatchedMultirotor` (torch, adaptive dopri5) integrates all starts together, one call
  per control step, commanded by motor speeds (`cmd_motor_speeds`); a crashed drone is no longer
  integrated. Its state: x, v (world), q (x, y, z, w, body to world), w (body rates), wind
  (airspeed of the air, world), rotor_speeds.
- Airframe `bfc`: the policy's own bfc airframe as a RotorPy params dict (mass and inertia of the
  rigid body MuJoCo compiles, rotors at bfc's positions and spins, k_f, k_m = moment_constant k_f,
  bfc's rotor drag) plus RotorPy's aerodynamics bfc does not model; one motor time constant, the
  mean of bfc's two. Airframe `rotorpy`: RotorPy's own vehicle for the policy's airframe (its
  Hummingbird or its Crazyflie, both "X"): the commands are permuted into RotorPy's rotor order,
  and for a "+" policy the policy's body frame is RotorPy's turned +45 deg in yaw, so that its
  rotor r1 is the policy's front motor (the odometry is expressed in that frame).
- Each control step the 18 odometry numbers are built as bfc's env builds them (position, velocity
  and velocity difference quotient in the world, ZYX roll/pitch/yaw, body rates and their
  difference quotient). `RotorPyPhysics` is the physics stage of bfc's pipeline
  (bfc.transforms.pipeline): the policy's maps, the flight loop and the judge are the ones MuJoCo
  flights run.
- The floor: RotorPy's own ground rule (Multirotor's `enable_ground`: clamp the height, no
  downward speed, horizontal damping, zero body rates, roll and pitch flattened), with the floor
  where a level bfc drone's centre rests (the airframe's ground height), since the batched vehicle has none.
  A crash is bfc's rule (bfc's hull touching the floor tilted or fast, or leaving the box).
"""

from __future__ import annotations

import dataclasses
import math
import time

import numpy as np
import torch
from tensordict import TensorDict

from bfc.agent import load_policy
from bfc.config import ROTORPY_AIRFRAMES
from bfc.envs import GOAL, REFERENCE_PHYSICS_DT, AirframeParams, TerminationParams
from bfc.envs.quadrotor import BODY, build_model
from bfc.envs.rotations import euler_to_quat, quat_to_euler
from bfc.evaluation.flights import fly_pipeline, one_torch_thread
from bfc.evaluation.flying import (
    PROTOCOL_HZ,
    airframe_of,
    controller_kinds,
    is_module,
    is_onnx_path,
    onnx_controller,
)
from bfc.evaluation.protocol import TEST_SEED
from bfc.evaluation.suites import CONDITIONS, robust_results
from bfc.factory import trained_rate
from bfc.transforms.pipeline import Physics, Pipeline, StepState

INSTALL_HINT = 'sim=rotorpy needs RotorPy: pip install -e ".[rotorpy]"'
# RotorPy's own vehicles (an "X": r1 front-left, r2 front-right, r3 back-right, r4 back-left), by
# the name of the bfc airframe they stand for: airframe "rotorpy" flies the one of the policy's
_VEHICLES = {"hummingbird": "hummingbird_params", "crazyflie": "crazyflie_params"}
_X_ORDER = (0, 3, 2, 1)  # RotorPy rotor i is bfc motor _X_ORDER[i] of an "x" (or the "+" turned 45 deg)
# RotorPy's Hummingbird aerodynamics that bfc's env does not model (flown on bfc's airframe too)
_RP_AERO = ("c_Dx", "c_Dy", "c_Dz", "k_z", "k_h", "k_flap")


def require_rotorpy() -> None:
    """Raise ValueError (one line, the install command) unless RotorPy and its batched vehicle's
    dependencies import."""
    try:
        import roma  # noqa: F401
        import rotorpy.vehicles.multirotor  # noqa: F401
        import torchdiffeq  # noqa: F401
    except ImportError as err:
        raise ValueError(f"{INSTALL_HINT} ({err})") from None


def _vehicle(name: str = "hummingbird") -> dict:
    """A copy of RotorPy's own params dict for the bfc airframe `name`."""
    import importlib

    if name not in _VEHICLES:
        raise ValueError(
            f"rotorpy_airframe=rotorpy flies RotorPy's own {' or '.join(_VEHICLES)}; this policy's airframe is "
            f"{name!r}: use rotorpy_airframe=bfc"
        )
    quad_params = importlib.import_module(f"rotorpy.vehicles.{_VEHICLES[name]}").quad_params
    return {k: (dict(v) if isinstance(v, dict) else v) for k, v in quad_params.items()}


def bfc_params(airframe: AirframeParams) -> dict:
    """A bfc airframe as a RotorPy params dict: the rigid body MuJoCo compiles from it (mass,
    inertia about the centre of mass), rotors at bfc's positions in bfc's motor order and spins,
    thrust k_f w^2, yaw moment moment_constant k_f w^2, bfc's rotor drag; RotorPy's own vehicle's
    values for the aerodynamics bfc lacks (its Hummingbird's for an airframe it has no model of);
    the mean of bfc's two motor time constants."""
    import mujoco

    body = build_model(airframe, REFERENCE_PHYSICS_DT).body(BODY)
    rot = np.zeros(9)
    mujoco.mju_quat2Mat(rot, body.iquat)
    rot = rot.reshape(3, 3)
    inertia = rot @ np.diag(body.inertia) @ rot.T
    com = np.array(body.ipos)
    a = airframe
    params = _vehicle(a.name if a.name in _VEHICLES else "hummingbird")
    params.update(
        mass=float(body.mass[0]),
        Ixx=inertia[0, 0],
        Iyy=inertia[1, 1],
        Izz=inertia[2, 2],
        Ixy=inertia[0, 1],
        Ixz=inertia[0, 2],
        Iyz=inertia[1, 2],
        num_rotors=4,
        rotor_pos={f"r{i + 1}": np.array(p) - com for i, p in enumerate(a.rotor_positions)},
        rotor_directions=np.array(a.rotor_spins),
        k_eta=a.motor_constant,
        k_m=a.moment_constant * a.motor_constant,
        k_d=a.rotor_drag_coefficient,
        tau_m=0.5 * (a.time_constant_up + a.time_constant_down),
        rotor_speed_min=a.min_rotor_speed,
        rotor_speed_max=a.max_rotor_speed,
        motor_noise_std=0.0,
    )
    return params


_SCALED = ("mass", "Ixx", "Iyy", "Izz", "k_eta", "k_m", "tau_m")


def rotorpy_params(nominal: AirframeParams, flown: AirframeParams) -> dict:
    """RotorPy's own vehicle for the nominal airframe (its Hummingbird or Crazyflie), with the
    mismatch of `flown` against `nominal` (e.g. a robustness row's) applied as the same ratios of
    mass, inertia, k_eta, k_m and tau_m."""
    params = _vehicle(nominal.name)
    if flown != nominal:
        before, after = bfc_params(nominal), bfc_params(flown)
        for k in _SCALED:
            params[k] = params[k] * after[k] / before[k]
    return params


def flight_params(kind: str, nominal: AirframeParams, flown: AirframeParams) -> dict:
    if kind not in ROTORPY_AIRFRAMES:
        raise ValueError(f"rotorpy_airframe must be one of {', '.join(ROTORPY_AIRFRAMES)}, got {kind!r}")
    return bfc_params(flown) if kind == "bfc" else rotorpy_params(nominal, flown)


def wind_speed_for_drag(params: dict, newtons: float) -> float:
    """The wind speed (m/s) whose drag on the vehicle, level at its hover speed, is `newtons`
    horizontally (RotorPy's parasitic and rotor drag): bfc's wind is a force, RotorPy's is air."""
    from rotorpy.vehicles.multirotor import Multirotor

    vehicle = Multirotor(params, aero=True)
    hover = np.full(4, math.sqrt(params["mass"] * vehicle.g / (4 * params["k_eta"])))

    def drag(speed: float) -> float:
        force, _ = vehicle.compute_body_wrench(np.zeros(3), hover, np.array([-speed, 0.0, 0.0]))
        return float(force[0])

    lo, hi = 0.0, 1.0
    while drag(hi) < newtons:
        lo, hi = hi, 2 * hi
        if hi > 1e3:
            raise ValueError(f"no wind below 1000 m/s drags {newtons} N on this airframe")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if drag(mid) < newtons else (lo, mid)
    return 0.5 * (lo + hi)


def _qmul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product of (..., 4) quaternions w, x, y, z."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack(
        (
            aw * bw - ax * bx - ay * by - az * bz,
            aw * bx + ax * bw + ay * bz - az * by,
            aw * by - ax * bz + ay * bw + az * bx,
            aw * bz + ax * by - ay * bx + az * bw,
        ),
        -1,
    )


class RotorPyQuads:
    """n RotorPy vehicles of one params dict, integrated together (BatchedMultirotor), seen and
    commanded as bfc's env is: bfc's odometry in the policy's frame, motor speeds in bfc's order."""

    def __init__(
        self, params: dict, n: int, dt: float, airframe: str = "bfc", wind=None, body: AirframeParams | None = None
    ):
        """airframe: "bfc" (params are `body`'s) or "rotorpy" (RotorPy's own X vehicle);
        body: the bfc airframe the policy knows (its layout, its hull for the floor and the crash
        rule; the Hummingbird by default)."""
        from rotorpy.vehicles.multirotor import BatchedMultirotor, BatchedMultirotorParams

        if airframe not in ROTORPY_AIRFRAMES:
            raise ValueError(f"rotorpy_airframe must be one of {', '.join(ROTORPY_AIRFRAMES)}, got {airframe!r}")
        self.n, self.dt, self.params = int(n), float(dt), params
        f64, cpu = torch.float64, torch.device("cpu")
        self.state = {k: torch.zeros(n, 3, dtype=f64) for k in ("x", "v", "w", "wind")}
        self.state["q"] = torch.tensor([0.0, 0.0, 0.0, 1.0], dtype=f64).repeat(n, 1)
        self.state["rotor_speeds"] = torch.zeros(n, 4, dtype=f64)
        if wind is not None:
            self.state["wind"][:] = torch.as_tensor(wind, dtype=f64)
        batch = BatchedMultirotorParams([params] * n, n, cpu)
        self.vehicle = BatchedMultirotor(batch, n, self.state, cpu, control_abstraction="cmd_motor_speeds")
        body = body or AirframeParams()
        own = airframe == "rotorpy"
        self.order = list(_X_ORDER if own else range(4))
        self.inverse = [self.order.index(j) for j in range(4)]
        half = 0.5 * (math.pi / 4 if own and body.layout == "+" else 0.0)
        self.q_bp = torch.tensor([math.cos(half), 0.0, 0.0, math.sin(half)], dtype=f64)  # policy frame in body
        c, s = math.cos(2 * half), math.sin(2 * half)
        self.r_bp = torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=f64)
        self.max_speed = float(params["rotor_speed_max"])
        self.ground, self.hull = body.ground_height, body.hull_half_size
        self.beta = min(0.5, max(0.1, float(params.get("ground_friction_beta", 0.3))))  # RotorPy's clamp
        self.termination = TerminationParams()
        self.alive = torch.ones(n, dtype=torch.bool)
        self.lin_acc, self.ang_acc = torch.zeros(n, 3, dtype=f64), torch.zeros(n, 3, dtype=f64)

    def place(self, starts: torch.Tensor, motor_speeds: float = 0.0) -> None:
        """Starts (n, 12) in bfc's `"start_state"` layout (attitude and body rates of the policy's
        frame); motors at `motor_speeds` (rad/s; bfc's flights start them at rest)."""
        s = torch.as_tensor(starts).to(torch.float64)
        if s.shape != (self.n, 12):
            raise ValueError(f"starts must have shape ({self.n}, 12), got {tuple(s.shape)}")
        conj = self.q_bp * torch.tensor([1.0, -1.0, -1.0, -1.0], dtype=torch.float64)
        q_wb = _qmul(euler_to_quat(s[:, 3:6]), conj)
        st = self.state
        st["x"][:], st["v"][:] = s[:, 0:3], s[:, 6:9]
        st["q"][:] = q_wb[:, [1, 2, 3, 0]]
        st["w"][:] = s[:, 9:12] @ self.r_bp.T
        st["rotor_speeds"][:] = float(motor_speeds)
        self.alive[:] = True
        self.lin_acc.zero_()
        self.ang_acc.zero_()

    # what bfc's env reports, in the policy's frame and bfc's motor order
    def quaternion(self) -> torch.Tensor:
        """(n, 4) w, x, y, z of the policy's frame (body to world)."""
        return _qmul(self.state["q"][:, [3, 0, 1, 2]], self.q_bp)

    def body_rates(self) -> torch.Tensor:
        return self.state["w"] @ self.r_bp

    def motor_speeds(self) -> torch.Tensor:
        return self.state["rotor_speeds"][:, self.inverse]

    def odometry(self) -> torch.Tensor:
        """(n, 18) float32, bfc's layout (bfc/keys.py)."""
        st = self.state
        parts = (st["x"], st["v"], self.lin_acc, quat_to_euler(self.quaternion()), self.body_rates(), self.ang_acc)
        return torch.cat(parts, -1).float()

    def step(self, command: torch.Tensor) -> None:
        """One control step under motor speed commands (n, 4), rad/s, bfc's motor order."""
        cmd = torch.as_tensor(command).detach().to(torch.float64)
        if cmd.shape != (self.n, 4):
            raise ValueError(f"command must have shape ({self.n}, 4) (motor speeds in rad/s), got {tuple(cmd.shape)}")
        if not bool(torch.isfinite(cmd).all()):
            raise ValueError("a controller must output finite rad/s: the command has NaN or infinite motor speeds")
        cmd = cmd.clamp(0.0, self.max_speed)[:, self.order]
        st = self.state
        old_v, old_w = st["v"].clone(), self.body_rates()
        idxs = self.alive.nonzero().flatten()
        if idxs.numel():
            new = self.vehicle.step(st, {"cmd_motor_speeds": cmd}, self.dt, idxs)
            for k in st:
                st[k][idxs] = new[k][idxs]
            self._ground(idxs)
        self.lin_acc = (st["v"] - old_v) / self.dt
        self.ang_acc = (self.body_rates() - old_w) / self.dt
        self.alive &= ~self._crashed(old_v[:, 2])

    def _ground(self, idxs: torch.Tensor) -> None:
        """RotorPy's ground rule (Multirotor._handle_vehicle_on_ground), the floor at the height of
        a level bfc drone's centre."""
        from scipy.spatial.transform import Rotation

        st = self.state
        on = idxs[st["x"][idxs, 2] <= self.ground + 0.001]
        if not on.numel():
            return
        st["x"][on, 2] = self.ground
        st["v"][on, 2] = st["v"][on, 2].clamp(min=0.0)
        st["v"][on, :2] *= 1.0 - self.beta
        st["w"][on] = 0.0
        heading = Rotation.from_quat(st["q"][on].numpy()).as_euler("XYZ")[:, 2]
        st["q"][on] = torch.from_numpy(Rotation.from_euler("Z", heading[:, None]).as_quat())

    def _crashed(self, prev_vz: torch.Tensor) -> torch.Tensor:
        """bfc's crash rule, QuadrotorEnv's own (TerminationParams.crashed): the hull touching the
        floor tipped over or hitting it hard, or leaving the box."""
        w, x, y, z = self.quaternion().unbind(-1)
        cos_tilt = 1 - 2 * (x * x + y * y)
        return self.termination.crashed(self.state["x"].unbind(-1), (w, x, y, z), cos_tilt, prev_vz, self.hull)


class RotorPyPhysics(Physics):
    """RotorPyQuads as the pipeline's physics stage: the outputs in QuadrotorEnv's FLAT_* layout
    (the odometry, the policy frame's quaternion, the motor speeds, the goal; no reward)."""

    def __init__(self, quads: RotorPyQuads, goal):
        self.quads = quads
        self.goal = torch.as_tensor(goal, dtype=torch.float32).expand(quads.n, 3).clone()

    def _observe(self, state: StepState) -> None:
        q = self.quads
        reward = torch.zeros(q.n, 1)
        parts = [q.odometry(), q.quaternion().float(), q.motor_speeds().float(), self.goal, reward]
        state.set_truth(torch.cat(parts, -1))

    def advance(self, state: StepState) -> None:
        self.quads.step(state.command if state.applied is None else state.applied)
        self._observe(state)
        state.terminated, state.truncated = ~self.quads.alive, torch.zeros(self.quads.n, dtype=torch.bool)

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        if not bool(mask.all()):
            raise ValueError("RotorPy flights start every vehicle together")
        self.quads.place(state.start)
        self._observe(state)

    def set_goal(self, state: StepState, goal) -> None:
        self.goal = torch.as_tensor(goal, dtype=torch.float32).expand(self.quads.n, 3).clone()
        state.goal = self.goal


def _resolve(controller, control_hz, nominal: AirframeParams | None = None):
    """(spec or None, the network or controller module, its control rate); a classical controller
    is built for `nominal` (the Hummingbird when None)."""
    from bfc.controllers import CONTROLLERS

    if isinstance(controller, (str, bytes)) and str(controller) in CONTROLLERS:
        rate = float(control_hz or PROTOCOL_HZ)
        return None, CONTROLLERS[str(controller)](nominal or AirframeParams(), 1.0 / rate), rate
    if is_module(controller):
        return None, controller, float(control_hz or PROTOCOL_HZ)
    if is_onnx_path(controller):
        return None, *onnx_controller(controller, control_hz)
    if isinstance(controller, (str, bytes)) or hasattr(controller, "__fspath__"):
        spec, net = load_policy(controller)
        return spec, net, trained_rate(spec.control_hz, control_hz)
    raise ValueError(f"controller must be {controller_kinds()}")


@torch.no_grad()
def fly_rotorpy(
    controller,
    starts,
    goal=GOAL,
    seconds: float = 10.0,
    airframe: str = "bfc",
    flown: dict | None = None,
    wind=None,
    wind_drag=None,
    control_hz=None,
    nominal: AirframeParams | None = None,
) -> TensorDict:
    """Fly all `starts` (n, 12) in RotorPy for `seconds`: `fly`'s arguments and trajectory keys.

    controller: a policy.pt path (flown at its own rate, through its maps, on its own airframe), a
    classical controller name (built for `nominal`, the Hummingbird when None, 250 Hz) or a
    TensorDictModule (odometry, goal -> action) flying `nominal`.
    airframe: "bfc" (the policy's bfc airframe in RotorPy) or "rotorpy" (RotorPy's own vehicle of it).
    flown: AirframeParams overrides of the flown body (a robustness row's mismatch).
    wind: the air's velocity (m/s, world), (3,) or (n, 3); wind_drag instead: forces (N, world,
    horizontal), (3,) or (n, 3), each flown as the air in its direction whose drag on the vehicle
    hovering level is that force (`wind_speed_for_drag`: bfc's wind is a force, RotorPy's is air).
    The trajectory's `"wind"` (n, T, 3) is the air flown.
    """
    require_rotorpy()
    starts = torch.as_tensor(starts, dtype=torch.float32)
    if starts.ndim != 2 or starts.shape[1] != 12:
        raise ValueError(f"starts must have shape (n, 12), got {tuple(starts.shape)}")
    if seconds <= 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    spec, net, rate = _resolve(controller, control_hz, nominal)
    nominal = dict(spec.airframe) if spec is not None else dataclasses.asdict(nominal or AirframeParams())
    params = flight_params(airframe, AirframeParams(**nominal), AirframeParams(**{**nominal, **dict(flown or {})}))
    n, dt = starts.shape[0], 1.0 / rate
    steps = round(seconds / dt)
    if wind_drag is not None:
        force = torch.as_tensor(wind_drag, dtype=torch.float64).expand(n, 3)
        size = force.norm(dim=-1, keepdim=True)
        speeds = torch.tensor([[wind_speed_for_drag(params, float(f)) if f > 0 else 0.0] for f in size[:, 0]])
        wind = torch.where(size > 0, force / size.clamp(min=1e-12), 0.0) * speeds
    quads = RotorPyQuads(params, n, dt, airframe, wind, AirframeParams(**nominal))
    maps = [spec.make_observation_map(n, dt), spec.make_action_map()] if spec is not None else []
    pipeline = Pipeline(maps, RotorPyPhysics(quads, goal), n)  # make_env's order: observation, action
    begin = getattr(net, "begin_flight", None)
    if callable(begin):
        begin()
    with one_torch_thread():
        out, seconds_per_call = fly_pipeline(pipeline, net, steps, start=starts)
    out["time"] = torch.tensor([(t + 1) * dt for t in range(steps)]).expand(n, steps).clone()
    out["controller_seconds"] = torch.tensor(seconds_per_call).expand(n, steps).clone()
    out["wind"] = quads.state["wind"].float().unsqueeze(1).expand(n, steps, 3).clone()
    return out


def fly_condition_rotorpy(
    controller,
    name: str,
    num_starts: int = 100,
    seed: int = TEST_SEED,
    seconds: float = 10.0,
    airframe: str = "bfc",
    nominal: AirframeParams | None = None,
) -> TensorDict:
    """`suites.fly_condition` in RotorPy: the row's starts and mismatch; its wind (a force in
    bfc) as the air whose drag at hover is that force (see `fly_rotorpy`'s wind_drag). The
    controller flies its airframe: a policy's own, else `nominal` (the Hummingbird when None)."""
    if name not in CONDITIONS:
        raise ValueError(f"unknown condition {name!r}; available: {', '.join(CONDITIONS)}")
    body = airframe_of(controller, nominal)
    starts, wind, flown = CONDITIONS[name].world(body, num_starts, seed)
    return fly_rotorpy(
        controller, starts, seconds=seconds, airframe=airframe, flown=flown, wind_drag=wind, nominal=body
    )


def robust_results_rotorpy(
    controllers: dict,
    names=None,
    num_starts: int = 100,
    seed: int = TEST_SEED,
    protocol=None,
    airframe: str = "bfc",
    nominal: AirframeParams | None = None,
) -> dict:
    """`suites.robust_results` in RotorPy: {row: {label: score}}, each score with the row's wall
    clock (`wall_seconds`) and, for the wind row, the RotorPy wind speed flown (`wind_m_s`)."""
    started = [time.perf_counter()]

    def fly_row(controller, name, n, row_seed, seconds, nominal):
        started[0] = time.perf_counter()
        return fly_condition_rotorpy(controller, name, n, row_seed, seconds, airframe, nominal)

    def timed(name, label, flights) -> dict:
        speed = flights.get("wind")[:, 0].norm(dim=-1).max().item()
        wind = {"wind_m_s": round(speed, 2)} if speed else {}
        return {"wall_seconds": round(time.perf_counter() - started[0], 1), **wind}

    return robust_results(
        controllers, names, num_starts, seed, protocol, on_flights=timed, fly_row=fly_row, airframe=nominal
    )
