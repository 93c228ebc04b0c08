"""N quadrotors (AscTec Hummingbirds by default, any `AirframeParams`) in MuJoCo as one batched TorchRL env.

Why it is built this way:
- MuJoCo integrates rigid-body and contact dynamics; everything MuJoCo has no element for (the
  asymmetric first-order motor lag, thrust = k_f w^2, rotor drag) is batched tensor code here.
- Within one control step the motor command is constant, so the motor lag has a closed form: the
  thrust of every physics substep is known before the step and the whole batch is integrated with
  one threaded `mujoco.rollout` call (no Python loop over envs or substeps).
- The four thrusts reach MuJoCo as one body-frame wrench (force and torque actuators at the body's
  origin), so a randomised mass or inertia is a per-env gain on that wrench (a body of mass m'
  under force F moves as the nominal body under F m / m'): every env steps the same compiled model.
- Rotor drag depends on the velocity, so it is held constant over the control step.
- `physics_dt` is the MuJoCo step: 0.002 s (the reference simulator every evaluation flies) by
  default; training may take one step per control step (docs/env.md, "Physics step").
"""

from __future__ import annotations

import math
import os
from importlib import resources

import mujoco
import mujoco.rollout
import numpy as np
import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.data import Bounded, Categorical, Composite, Unbounded
from torchrl.envs import EnvBase

from bfc import keys
from bfc.checks import check as _check
from bfc.envs.params import (  # the task's parameters live with the airframe's: no torch to check a config
    AIRFRAME_RANGES,
    REFERENCE_PHYSICS_DT,
    AirframeParams,
    EnvParams,
    as_params,
)
from bfc.envs.rotations import euler_to_quat

# Layout of MuJoCo's mjSTATE_FULLPHYSICS vector for this model: time, qpos (3 + 4), qvel (3 + 3).
_POS, _QUAT, _LINVEL, _ANGVEL = slice(1, 4), slice(4, 8), slice(8, 11), slice(11, 14)
BODY = "quadrotor"  # the asset's free body

# Layout of the one float32 buffer (N, 30) a step writes (`QuadrotorEnv.advance`); every output
# key is a view into it (`QuadrotorEnv.pack`).
FLAT_SIZE = 30
FLAT_ODOMETRY, FLAT_QUATERNION, FLAT_MOTORS, FLAT_GOAL, FLAT_REWARD = (
    slice(0, 18),
    slice(18, 22),
    slice(22, 26),
    slice(26, 29),
    slice(29, 30),
)
# inside the odometry (bfc.keys.ODOMETRY's layout): position, velocity, accelerations, Euler angles, rates
FLAT_POSITION, FLAT_LINEAR_VELOCITY, FLAT_ANGULAR_VELOCITY = slice(0, 3), slice(3, 6), slice(12, 15)


def state_views(flat: torch.Tensor) -> dict:
    """The env's `"state"` entries (ground truth) as views into outputs (..., 30)."""
    return {
        "position": flat[..., FLAT_POSITION],
        "quaternion": flat[..., FLAT_QUATERNION],
        "linear_velocity": flat[..., FLAT_LINEAR_VELOCITY],
        "angular_velocity": flat[..., FLAT_ANGULAR_VELOCITY],
        "motor_speeds": flat[..., FLAT_MOTORS],
    }


def _body_xy_velocity(phys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Body-frame x and y of the linear velocity, R(q)^T v, for physics states (N, 14)."""
    w, x, y, z, vx, vy, vz = phys[:, 4:11].T
    # t = 2 (u x v) with u = -(x, y, z), the conjugate's vector part; result v + w t + u x t.
    tx, ty, tz = 2 * (z * vy - y * vz), 2 * (x * vz - z * vx), 2 * (y * vx - x * vy)
    return vx + w * tx + (z * ty - y * tz), vy + w * ty + (x * tz - z * tx)


def build_model(airframe: AirframeParams, physics_dt: float) -> mujoco.MjModel:
    """Compile the shipped MJCF with the given airframe parameters (masses, inertia, rotor
    positions, collision box); the rotors' thrust and moments are the env's wrench, not the model's."""
    return airframe_spec(airframe, physics_dt).compile()


def airframe_spec(airframe: AirframeParams, physics_dt: float = REFERENCE_PHYSICS_DT) -> mujoco.MjSpec:
    """The shipped MJCF as an editable MjSpec with the airframe's values (the video adds visuals)."""
    path = resources.files("bfc.envs") / "assets" / "quadrotor.xml"
    spec = mujoco.MjSpec.from_file(str(path))
    spec.option.timestep = physics_dt
    spec.option.gravity = [0.0, 0.0, -airframe.gravity]
    body = spec.body(BODY)
    body.mass = airframe.body_mass
    body.inertia = list(airframe.inertia)
    spec.geom("hull").size = list(airframe.hull_half_size)
    spec.body("imu").mass = airframe.imu_mass
    for i, position in enumerate(airframe.rotor_positions):
        rotor = spec.body(f"rotor_{i}")
        rotor.mass = airframe.rotor_mass
        rotor.pos = list(position)
    return spec


class QuadrotorEnv(EnvBase):
    """`num_envs` quadrotors of one airframe flown by motor speed commands (rad/s).

    Keys: `"action"` (N, 4) in; `"odometry"` (N, 18), `"goal"` (N, 3) and ground truth under
    `"state"` out (see bfc.keys). `reset()` draws starts from the task distribution D; a reset
    tensordict may carry `"start_state"` (N, 12) to place envs exactly. NaN entries of a start
    state mean "draw this entry from D", so samplers can each fill in the part they own.
    """

    batch_locked = True

    def __init__(
        self,
        num_envs: int = 1,
        params: EnvParams | dict | None = None,
        *,
        num_threads: int | None = None,
        seed: int | None = None,
        device: str = "cpu",
        **changes,
    ):
        """params: an EnvParams (a mapping of its fields; None: the defaults); `changes`: any of
        its fields by keyword, e.g. `QuadrotorEnv(4, start_motors="hover")`. num_threads: MuJoCo's
        rollout threads (None: all cores); seed: the env's generator (starts, randomisation)."""
        p = self.params = as_params(EnvParams, params, **changes)
        _check(isinstance(num_envs, int) and num_envs >= 1, "env.num_envs", "an integer >= 1", num_envs)
        if num_threads is None:
            num_threads = os.cpu_count() or 1
        _check(isinstance(num_threads, int) and num_threads >= 1, "env.num_threads", "an integer >= 1", num_threads)
        super().__init__(device=device, batch_size=torch.Size([num_envs]))

        self.num_envs = num_envs
        self.airframe, self.reward_params, self.termination = p.airframe, p.reward, p.termination
        self.start_params, self.randomize = p.start, p.randomize
        # How much of the `randomize` ranges is drawn from, in [0, 1]: a training curriculum
        # (bfc.collectors.curriculum) widens it from a start fraction to 1; ranges shrink towards 1
        # (the nominal airframe) and the wind towards 0. Set between batches, never mid-episode.
        self.randomize_scale = 1.0
        self.control_hz, self.physics_dt, self.substeps = float(p.control_hz), p.physics_step, p.substeps
        self.dt = self.substeps * self.physics_dt
        self.max_episode_steps = max(1, round(p.episode_seconds / self.dt))
        self.hover_speed = self.airframe.hover_speed
        self.max_rotor_speed = self.airframe.max_rotor_speed
        self.ground_height = self.airframe.ground_height
        self.num_threads = num_threads
        self.start_motors = p.start_motors
        self.physics_failures = 0  # envs whose state became non-finite (terminated and replaced)

        self.model = build_model(self.airframe, self.physics_dt)
        self._datas = [mujoco.MjData(self.model) for _ in range(num_threads)]
        self._models = [self.model] * num_envs  # the rollout takes one model per env: all the same one
        self._rollout = mujoco.rollout.Rollout(nthread=num_threads)
        self._nstate = mujoco.mj_stateSize(self.model, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        assert self._nstate == 14, "asset layout changed: update the state slices"
        assert self.model.nu == 9, "asset actuators changed: update the wrench columns"

        self._allocate_state(num_envs, p.goal)
        # the rotor layout as wrench rows: torque x = sum y_i T_i, torque y = -sum x_i T_i,
        # torque z = moment_constant sum spin_i T_i (AirframeParams.torque_rows)
        # (4, 3): thrusts (..., 4) @ rows -> torques; built (3, 4) and transposed, a column-major view
        # as it always was: the product's summation order, and so its last bits, follow the layout
        self._torque_rows = np.array(list(zip(*self.airframe.torque_rows(), strict=True))).T
        self._hull = self.airframe.hull_half_size
        self._generator = torch.Generator()
        self._generator.manual_seed(0 if seed is None else seed)
        self._make_specs()

    def _allocate_state(self, num_envs: int, goal) -> None:
        """The per-env state (float64, as MuJoCo integrates) and the airframe multipliers. The hot
        path works on NumPy views (`*_np`) of these tensors: a NumPy op on a (N,) column costs a
        third of a torch op."""
        n, f64, substeps = num_envs, torch.float64, self.substeps
        self._physics = torch.zeros(n, self._nstate, dtype=f64)
        self._physics_np = self._physics.numpy()
        self._out = np.zeros((n, substeps, self._nstate))
        # MuJoCo's controls per substep: body force (3) and torque (3), external force (3, world)
        self._ctrl = torch.zeros(n, substeps, self.model.nu, dtype=f64)
        self._ctrl_np = self._ctrl.numpy()
        self._external = torch.zeros(n, 3, dtype=f64)  # the external force as set (N, world frame)
        self._obs_np = np.zeros((n, FLAT_SIZE))  # staging buffer for the outputs (see observe)
        self._motor = torch.zeros(n, 4, dtype=f64)
        self._motor_np = self._motor.numpy()
        self._lin_acc = torch.zeros(n, 3, dtype=f64)
        self._lin_acc_np = self._lin_acc.numpy()
        self._ang_acc = torch.zeros(n, 3, dtype=f64)
        self._ang_acc_np = self._ang_acc.numpy()
        self._steps = torch.zeros(n, dtype=torch.long)
        self._steps_np = self._steps.numpy()
        self._goal = torch.tensor(goal, dtype=torch.float32).expand(n, 3).clone()
        # Per-env airframe multipliers (randomised per episode by `env.randomize`, else ones):
        # mass, inertia, motor constant, motor time constants. From them: the wrench gains (the
        # nominal body's mass and inertia over the flown one's), the thrust constant k_f and the
        # closed-form motor lag, the decay exp(-t / tau) at each substep's midpoint (for the thrust
        # of that substep) and at the end of the step, for speeding up and for slowing down.
        self._airframe_scale = torch.ones(n, 4, dtype=f64)
        self._airframe_scale_np = self._airframe_scale.numpy()
        self._force_gain = np.ones((n, 1))
        self._torque_gain = np.ones((n, 1, 3))
        self._kf = np.full((n, 1, 1), self.airframe.motor_constant)
        self._mid = ((np.arange(substeps) + 0.5) * self.physics_dt).reshape(1, substeps, 1)
        self._decay_sub = (np.empty((n, substeps, 1)), np.empty((n, substeps, 1)))
        self._decay_step = (np.empty((n, 1)), np.empty((n, 1)))
        self._apply_airframe_scale(np.ones(n, dtype=bool))

    def _apply_airframe_scale(self, m: np.ndarray) -> None:
        """Recompute the wrench gains and the motor model of the envs in mask `m` from their
        airframe multipliers (mass, inertia, motor constant, motor lag)."""
        a, scale = self.airframe, self._airframe_scale_np[m]
        self._force_gain[m, 0] = a.mass_gain(scale[:, 0])
        rigid, base = np.array(a.rigid_inertia), np.array(a.inertia)
        self._torque_gain[m, 0] = rigid / (rigid + base * (scale[:, 1:2] - 1))
        self._kf[m, 0, 0] = a.motor_constant * scale[:, 2]
        taus = (a.time_constant_up, a.time_constant_down)
        for decay_sub, decay_step, tau in zip(self._decay_sub, self._decay_step, taus, strict=True):
            t = (tau * scale[:, 3]).reshape(-1, 1, 1)
            decay_sub[m] = np.exp(-self._mid / t)
            decay_step[m] = np.exp(-self.dt / t[:, 0])
        self._write_external(m)

    @property
    def airframe_scale(self) -> dict:
        """Each env's flown airframe as multipliers of the nominal one (N,) each: what
        `env.randomize` drew for the current episode (all ones when off)."""
        return {name: self._airframe_scale[:, col].clone() for col, name in enumerate(AIRFRAME_RANGES)}

    def _randomize_airframe(self, m: np.ndarray) -> None:
        """Draw a new airframe for the envs in mask `m` (only the ranges that are on draw)."""
        r, k, g, scale = self.randomize, int(m.sum()), self._generator, self.randomize_scale
        changed = False
        for col, name in enumerate(AIRFRAME_RANGES):
            if r.active(name):
                low, high = (1 + scale * (v - 1) for v in getattr(r, name))
                u = torch.rand(k, generator=g, dtype=torch.float64).numpy()
                self._airframe_scale_np[m, col] = low + (high - low) * u
                changed = True
        if not changed:
            return
        if r.min_thrust_to_weight > 0:  # too weak to climb: stronger motors, no new draw
            a, scale = self.airframe, self._airframe_scale_np[m]
            scale[:, 2] = np.maximum(
                scale[:, 2], r.min_thrust_to_weight / (a.thrust_to_weight * a.mass_gain(scale[:, 0]))
            )
            self._airframe_scale_np[m] = scale
        self._apply_airframe_scale(m)

    # ----------------------------------------------------------------- specs
    def _make_specs(self) -> None:
        n = self.num_envs
        vec = lambda k: Unbounded(shape=(n, k), dtype=torch.float32)  # noqa: E731
        self.observation_spec = Composite(
            {
                keys.ODOMETRY: vec(18),
                keys.GOAL: vec(3),
                keys.STATE: Composite(
                    position=vec(3),
                    quaternion=vec(4),
                    linear_velocity=vec(3),
                    angular_velocity=vec(3),
                    motor_speeds=vec(4),
                    shape=(n,),
                ),
            },
            shape=(n,),
        )
        self.action_spec = Bounded(low=0.0, high=self.max_rotor_speed, shape=(n, 4), dtype=torch.float32)
        self.reward_spec = Unbounded(shape=(n, 1), dtype=torch.float32)
        flag = lambda: Categorical(2, shape=(n, 1), dtype=torch.bool)  # noqa: E731
        self.done_spec = Composite(done=flag(), terminated=flag(), truncated=flag(), shape=(n,))

    # ----------------------------------------------------------------- public helpers
    @property
    def goal(self) -> torch.Tensor:
        """(N, 3) the desired position of each env (world frame; a copy). Also an output (`"goal"`)."""
        return self._goal.clone()

    def set_goal(self, goal, env_ids: torch.Tensor | None = None) -> None:
        """Set the desired position of all envs, or of `env_ids` (a mask or indices)."""
        goal = torch.as_tensor(goal, dtype=torch.float32)
        if goal.shape[-1:] != (3,):
            raise ValueError(f"goal must have shape (3,) or (n, 3), got {tuple(goal.shape)}")
        if not bool(torch.isfinite(goal).all()):
            raise ValueError(f"goal must be finite (x, y, z in metres), got {goal.tolist()}")
        if env_ids is None:
            self._goal[:] = goal
        else:
            self._goal[env_ids] = goal

    @property
    def external_force(self) -> torch.Tensor:
        """(N, 3) the constant external force on each body (N, world frame; a copy)."""
        return self._external.float()

    def set_external_force(self, force, env_ids: torch.Tensor | None = None) -> None:
        """A constant force (newtons, world frame) on the body's centre: wind, a tether, a push.
        `force` is (3,) or (n, 3); it stays until set again (it is not reset with the episode)."""
        force = torch.as_tensor(force, dtype=torch.float64)
        rows = np.ones(self.num_envs, dtype=bool)
        if env_ids is not None:
            rows = np.zeros(self.num_envs, dtype=bool)
            rows[torch.as_tensor(env_ids).numpy()] = True
        count = int(rows.sum())
        if force.shape not in ((3,), (count, 3)):
            raise ValueError(
                f"external_force must have shape (3,) or ({count}, 3) (newtons, world frame), got {tuple(force.shape)}"
            )
        if not bool(torch.isfinite(force).all()):
            raise ValueError(f"external_force must be finite, got {force.tolist()}")
        self._external.numpy()[rows] = force.numpy()
        self._write_external(rows)

    def _write_external(self, m: np.ndarray) -> None:
        """The external force of the envs in mask `m` as MuJoCo controls (scaled by the mass gain)."""
        self._ctrl_np[m, :, 6:9] = (self._external.numpy()[m] * self._force_gain[m])[:, None, :]

    def sample_default_starts(self, n: int | None = None) -> torch.Tensor:
        """(n, 12) starts from the task distribution D: on the floor, level, at rest."""
        n = self.num_envs if n is None else n
        g = self._generator
        xy = torch.rand(n, 2, generator=g, dtype=torch.float64).numpy()
        yaw = torch.rand(n, generator=g, dtype=torch.float64).numpy()
        start = np.zeros((n, 12))
        start[:, 0:2] = (xy * 2 - 1) * self.start_params.xy_range
        start[:, 2] = self.ground_height
        start[:, 5] = (yaw * 2 - 1) * math.radians(self.start_params.yaw_range_deg)
        return torch.from_numpy(start)

    # ----------------------------------------------------------------- state (checkpoints)
    _STATE = ("physics", "motor", "lin_acc", "ang_acc", "steps", "goal", "external", "airframe_scale")

    def get_extra_state(self) -> dict:
        """Everything that evolves between steps (physics, motor speeds, accelerations, step
        counters, goals, the start generator): part of `state_dict()`, so the state dict of a
        `make_env` env (transforms included) is a whole snapshot that resumes bit-identically."""
        state = {name: getattr(self, f"_{name}").clone() for name in self._STATE}
        state["generator"] = self._generator.get_state()
        state["physics_failures"] = torch.tensor(self.physics_failures)
        return state

    def set_extra_state(self, state: dict) -> None:
        missing = [name for name in self._STATE if name not in state]
        if missing:
            raise ValueError(
                f"env state lacks {', '.join(missing)}: "
                "a checkpoint from an older bfc version, which this one cannot resume"
            )
        for name in self._STATE:
            mine, theirs = getattr(self, f"_{name}"), state[name]
            if theirs.shape != mine.shape:
                raise ValueError(
                    f"env state {name!r} has shape {tuple(theirs.shape)}, this env needs {tuple(mine.shape)} "
                    "(a checkpoint of another num_envs?)"
                )
            mine.copy_(theirs)  # in place: the NumPy views of the hot path stay valid
        self._generator.set_state(state["generator"])
        self.physics_failures = int(state["physics_failures"])
        self._apply_airframe_scale(np.ones(self.num_envs, dtype=bool))

    # ----------------------------------------------------------------- TorchRL hooks
    def _set_seed(self, seed: int | None) -> None:
        self._generator.manual_seed(0 if seed is None else int(seed))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        n = self.num_envs
        mask = torch.ones(n, dtype=torch.bool)
        given = None
        if tensordict is not None:
            if keys.RESET in tensordict.keys():
                mask = tensordict.get(keys.RESET).reshape(n).to(torch.bool)
            given = tensordict.get(keys.START_STATE, None)
        none = torch.zeros(n, dtype=torch.bool)
        return self.pack(self.restart(mask, given), none, none.clone(), reward=False)

    def restart(self, mask: torch.Tensor, start_state: torch.Tensor | None = None) -> torch.Tensor:
        """New episodes for the envs in `mask` (N,) bool, at `start_state` (N, 12) where it is not
        NaN and from the task distribution D elsewhere: what `reset()` runs, returning the outputs
        (N, 30) of every env (FLAT_* layout)."""
        n = self.num_envs
        start = self.sample_default_starts()
        if start_state is not None:
            if start_state.shape != (n, 12):
                raise ValueError(f"start_state must have shape ({n}, 12), got {tuple(start_state.shape)}")
            given = start_state.to(torch.float64)
            start = torch.where(torch.isnan(given), start, given)
        self.place(start, mask)
        return self.observe()

    def place(self, start: torch.Tensor, mask: torch.Tensor) -> None:
        """Write starts (N, 12) into the envs selected by the boolean `mask` (N,).

        Motors start at rest, or with `start_motors="hover"` at hover speed when the start is in
        the air (a drone perturbed in flight rather than dropped).
        """
        m = mask.numpy()
        if not m.any():
            return
        start = start.to(torch.float64)
        s = start.numpy()[m]
        # The quaternions of the whole batch, so that an env's start does not depend on which
        # other envs are placed with it (vectorised and scalar sin/cos can differ in the last bit).
        quat = euler_to_quat(start[:, 3:6]).numpy()[m]
        phys = self._physics_np
        phys[m, 1:4] = s[:, 0:3]
        phys[m, 4:8] = quat
        phys[m, 8:14] = s[:, 6:12]
        spin = 0.0
        if self.start_motors == "hover":
            spin = np.where(s[:, 2:3] > self.ground_height + 0.01, self.hover_speed, 0.0)
        self._motor_np[m] = spin
        self._lin_acc_np[m] = 0.0
        self._ang_acc_np[m] = 0.0
        self._steps_np[m] = 0
        if self.randomize.external_force > 0:  # a new wind for each new episode
            u = torch.rand(int(m.sum()), 2, generator=self._generator, dtype=torch.float64).numpy()
            size = u[:, 0] * self.randomize.external_force * self.randomize_scale
            angle = (u[:, 1] * 2 - 1) * math.pi
            self._external.numpy()[m] = np.stack((size * np.cos(angle), size * np.sin(angle), np.zeros_like(size)), -1)
        self._randomize_airframe(m)
        self._write_external(m)

    def _step(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self.pack(*self.advance(tensordict.get(keys.ACTION)))

    def advance(self, command: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """One control step of every env under motor speed commands (N, 4) in rad/s:
        (outputs (N, 30) float32 in the FLAT_* layout, terminated (N,), truncated (N,)).

        What `step()` runs, without a TensorDict around it (bfc's own fused collector and flight
        loop call it directly; `pack` turns its outputs into the env's keys)."""
        if command.shape != (self.num_envs, 4):
            raise ValueError(
                f"action must have shape ({self.num_envs}, 4) (motor speeds in rad/s), got {tuple(command.shape)}"
            )
        # The hot path is NumPy float64 on views of the state tensors, one (N,) column at a time:
        # MuJoCo integrates in float64 anyway, and a reduction over a short last axis (`.sum(-1)`)
        # costs as much as fifteen column operations.
        cmd = command.detach().numpy().astype(np.float64)
        if not np.isfinite(cmd).all():
            bad = np.flatnonzero(~np.isfinite(cmd).all(-1))[:8].tolist()
            raise ValueError(
                f"action has NaN or infinite motor speeds for envs {bad}; a controller must output finite rad/s"
            )
        a = self.airframe
        np.clip(cmd, a.min_rotor_speed, a.max_rotor_speed, out=cmd)
        w0 = self._motor_np
        up = cmd >= w0
        lag = w0 - cmd
        thrust = np.where(up[:, None], *self._decay_sub)  # (N, substeps, 4): lag decay, then speed, then thrust
        thrust *= lag[:, None]
        thrust += cmd[:, None]
        thrust *= self._kf * thrust
        old = self._physics_np.copy()
        vx, vy = _body_xy_velocity(old)
        spin = w0[:, 0] + w0[:, 1] + w0[:, 2] + w0[:, 3]  # motor speeds are never negative
        drag, rolling = -a.rotor_drag_coefficient * spin, -a.rolling_moment_coefficient * spin
        # the body wrench: rotor drag and the summed thrust, the thrusts' torques and reaction
        # moments plus the rolling moment, each times the env's gain (mass or inertia)
        ctrl, gain = self._ctrl_np, self._force_gain  # gain (N, 1)
        ctrl[:, :, 0] = (drag * vx)[:, None] * gain
        ctrl[:, :, 1] = (drag * vy)[:, None] * gain
        ctrl[:, :, 2] = (thrust[..., 0] + thrust[..., 1] + thrust[..., 2] + thrust[..., 3]) * gain
        torque = thrust @ self._torque_rows
        torque[..., 0] += (rolling * vx)[:, None]
        torque[..., 1] += (rolling * vy)[:, None]
        np.multiply(torque, self._torque_gain, out=ctrl[:, :, 3:6])
        self._integrate()
        w0[:] = cmd + lag * np.where(up, *self._decay_step)
        new = self._physics_np
        new[:] = self._out[:, -1]

        # Physics failures: terminate that env and put it somewhere finite; never crash the batch.
        # MuJoCo resets a diverged mjData itself (time restarts at 0), so a clock that did not
        # advance is a failure too.
        late = new[:, 0] < old[:, 0] + self.dt - 0.5 * self.physics_dt
        failed = None
        if not np.isfinite(new).all() or late.any():
            failed = ~np.isfinite(new).all(-1) | late
            self.physics_failures += int(failed.sum())
            self.place(self.sample_default_starts(), torch.from_numpy(failed))
        self._lin_acc_np[:] = (new[:, _LINVEL] - old[:, _LINVEL]) / self.dt
        self._ang_acc_np[:] = (new[:, _ANGVEL] - old[:, _ANGVEL]) / self.dt
        if failed is not None:
            self._lin_acc_np[failed] = 0.0
            self._ang_acc_np[failed] = 0.0
        self._steps_np += 1

        reward, crashed = self._reward_and_crash(new, cmd, old[:, 10])
        if failed is not None:
            crashed |= failed
        truncated = (self._steps_np >= self.max_episode_steps) & ~crashed
        return self.observe(reward), torch.from_numpy(crashed), torch.from_numpy(truncated)

    def _integrate(self) -> None:
        self._rollout.rollout(
            self._models,
            self._datas,
            self._physics_np,
            self._ctrl_np,
            state=self._out,
            skip_checks=True,
            nstep=self.substeps,
        )

    def _reward_and_crash(self, phys: np.ndarray, cmd: np.ndarray, prev_vz: np.ndarray):
        """Shaped reward (see RewardParams) and the crash flag (see TerminationParams)."""
        rp = self.reward_params
        px, py, pz, w, x, y, z, vx, vy, vz, wx, wy, wz = phys[:, 1:14].T
        g = self._goal.numpy()
        dx, dy, dz = px - g[:, 0], py - g[:, 1], pz - g[:, 2]
        dist = np.sqrt(dx * dx + dy * dy + dz * dz)
        cos_tilt = 1 - 2 * (x * x + y * y)  # world-z component of the body z axis
        if rp.kind == "paper":
            roll = np.arctan2(2 * (w * x + y * z), cos_tilt)
            pitch = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
            yaw = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
            r = -(rp.position * dist + rp.tilt * (np.abs(roll) + np.abs(pitch)) + rp.yaw * np.abs(yaw))
            return self._crashed_reward(r, phys, cos_tilt, prev_vz)
        act = (cmd - self.hover_speed) / self.hover_speed
        act *= act
        penalty = rp.position * dist + rp.tilt * (1 - cos_tilt)
        if rp.yaw:  # free by default: skip the trigonometry
            penalty += rp.yaw * (1 - np.cos(np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))))
        # one term at a time: the sum keeps the order of RewardParams (and so its last bits)
        penalty += rp.velocity * (vx * vx + vy * vy + vz * vz)
        penalty += rp.angular_velocity * (wx * wx + wy * wy + wz * wz)
        penalty += rp.yaw_rate * (wz * wz)
        penalty += rp.action * (act[:, 0] + act[:, 1] + act[:, 2] + act[:, 3])
        r = rp.alive * np.exp(-penalty / rp.alive) + rp.precision * np.exp(-np.square(dist / rp.precision_radius))
        return self._crashed_reward(r, phys, cos_tilt, prev_vz)

    def _crashed_reward(self, r: np.ndarray, phys: np.ndarray, cos_tilt: np.ndarray, prev_vz: np.ndarray):
        """(scale * (r - crash_penalty where crashed), crashed): the crash rule of TerminationParams."""
        rp, tp = self.reward_params, self.termination
        crashed = tp.crashed(phys[:, 1:4].T, phys[:, 4:8].T, cos_tilt, prev_vz, self._hull)
        r = np.where(crashed, r - rp.crash_penalty, r) * rp.scale
        return r, crashed

    def observe(self, reward: np.ndarray | None = None) -> torch.Tensor:
        """Every output of the current state in one new float32 buffer (N, 30), FLAT_* layout
        (odometry, quaternion, motor speeds, goal; the step's reward, 0 after a reset)."""
        buf, p = self._obs_np, self._physics_np
        w, x, y, z = p[:, _QUAT].T
        buf[:, 0:3] = p[:, _POS]
        buf[:, 3:6] = p[:, _LINVEL]
        buf[:, 6:9] = self._lin_acc_np
        buf[:, 9] = np.arctan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
        buf[:, 10] = np.arcsin(np.clip(2 * (w * y - z * x), -1.0, 1.0))
        buf[:, 11] = np.arctan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
        buf[:, 12:15] = p[:, _ANGVEL]
        buf[:, 15:18] = self._ang_acc_np
        buf[:, 18:22] = p[:, _QUAT]
        buf[:, 22:26] = self._motor_np
        buf[:, 26:29] = self._goal.numpy()
        buf[:, 29] = 0.0 if reward is None else reward
        return torch.from_numpy(buf.astype(np.float32))

    def pack(self, flat: torch.Tensor, terminated, truncated, reward: bool = True) -> TensorDictBase:
        """The env's keys as views into `flat` (N, 30) (or (..., N, 30): a stack of steps)."""
        out = {
            keys.ODOMETRY: flat[..., FLAT_ODOMETRY],
            keys.GOAL: flat[..., FLAT_GOAL],
            keys.STATE: state_views(flat),
            keys.TERMINATED: terminated.unsqueeze(-1),
            keys.TRUNCATED: truncated.unsqueeze(-1),
            keys.DONE: (terminated | truncated).unsqueeze(-1),
        }
        if reward:
            out[keys.REWARD] = flat[..., FLAT_REWARD]
        return TensorDict(out, batch_size=flat.shape[:-1], device=self.device)

    def close(self, *, raise_if_closed: bool = True) -> None:
        if self._rollout is not None:
            self._rollout.close()
            self._rollout = None
        super().close(raise_if_closed=raise_if_closed)
