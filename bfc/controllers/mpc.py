"""Kamel's linear MPC (ethz-asl/mav_control_rw, mav_linear_mpc) with its PID attitude loop.

Outer loop, every 1/rate_hz (held in between):
  state x = position (3), velocity (3), roll and pitch in the yaw-aligned frame (2), inputs
  u = roll command, pitch command, vertical thrust acceleration minus g. Model: p' = v,
  v' = (g pitch, -g roll, u_z) - drag v + d, roll' = (gain u_roll - roll) / tau (pitch alike),
  discretised exactly (zero-order hold) at prediction_dt; horizon of `horizon` steps; cost
  sum |x - x_ss|_Q + |u - u_ss|_R + |u_k - u_{k-1}|_R_delta, terminal cost from the discrete
  Riccati equation; input limits. The QP of every env is condensed (inputs only, box
  constraints) and all envs are solved at once as one block-diagonal OSQP problem, warm-started
  from the previous solve. If OSQP fails, the LQR of the same model (clipped) takes over.
  Offset-free: d is a low-passed estimate of the model's acceleration error.
Inner loop, every control step (mav_lowlevel_attitude_controller, PID_attitude_hummingbird.yaml):
  angular acceleration = (60 e_roll - 25 p + I_roll, 60 e_pitch - 22 q + I_pitch, 1.0 (r_cmd - r)),
  yaw rate command = 1.8 wrap(yaw_des - yaw) clipped to 90 deg/s (0 when the heading is held, the
  default: the task is yaw-free), torque = J alpha + w x J w,
  thrust = m (u_z + g) / (cos roll cos pitch), through the shared mixer to motor speeds.
The integrators accumulate the error once per 10 ms as the original (100 Hz) does.

The attitude-lag parameters (tau 0.2 / 0.23 s, gain 0.85 / 0.86) are the published Hummingbird
ones, not identified on this airframe (docs/controllers.md).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import osqp
import scipy.linalg
import scipy.sparse as sp
import torch

from bfc.controllers.base import Controller, Odometry
from bfc.envs.params import AirframeParams

# Statuses whose iterate is used (clipped to the box): one slow env in the batched problem must not
# send every env to the fallback. Anything else (infeasible, non-convex, ...) flies the LQR.
_USABLE = (
    osqp.SolverStatus.OSQP_SOLVED,
    osqp.SolverStatus.OSQP_SOLVED_INACCURATE,
    osqp.SolverStatus.OSQP_MAX_ITER_REACHED,
    osqp.SolverStatus.OSQP_TIME_LIMIT_REACHED,
)


@dataclass
class MPCParams:
    """The published Hummingbird set (linear_mpc_hummingbird.yaml, PID_attitude_hummingbird.yaml)."""

    roll_time_constant: float = 0.2
    pitch_time_constant: float = 0.23
    roll_gain: float = 0.85
    pitch_gain: float = 0.86
    drag: tuple[float, float, float] = (0.01, 0.01, 0.0)
    q_position: tuple[float, float, float] = (40.0, 40.0, 60.0)
    q_velocity: tuple[float, float, float] = (20.0, 20.0, 25.0)
    q_attitude: tuple[float, float] = (20.0, 20.0)
    r_command: tuple[float, float, float] = (35.0, 35.0, 2.0)
    r_delta: tuple[float, float, float] = (0.3, 0.3, 0.0025)
    roll_max_deg: float = 25.0
    pitch_max_deg: float = 25.0
    yaw_rate_max_deg: float = 90.0
    thrust_min: float = 5.0  # m/s^2, mass-normalised thrust
    thrust_max: float = 20.0
    k_yaw: float = 1.8
    yaw: float | None = None  # desired heading (rad); None: hold the current one (yaw rate command 0)
    horizon: int = 20
    prediction_dt: float = 0.1
    rate_hz: float = 100.0  # how often the QP is solved (the original: at the odometry rate)
    offset_free: bool = True
    disturbance_time_constant: float = 0.5  # s, low-pass of the disturbance estimate
    disturbance_max: float = 4.0  # m/s^2 per axis: room for a 30% heavier body or 20% weaker motors (~2.2)
    max_iter: int = 200  # OSQP iterations per solve; past it the LQR fallback flies
    # Attitude PID (inner loop)
    att_roll_gain: float = 60.0
    att_pitch_gain: float = 60.0
    att_p_gain: float = 25.0
    att_q_gain: float = 22.0
    att_r_gain: float = 1.0
    att_integrator_gain: float = 1.0
    att_integrator_max: float = 0.6

    def __post_init__(self) -> None:
        positive = (
            "roll_time_constant",
            "pitch_time_constant",
            "prediction_dt",
            "rate_hz",
            "disturbance_time_constant",
        )
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"mpc.{name} must be > 0, got {getattr(self, name)!r}")
        if self.horizon < 1 or self.max_iter < 1:
            raise ValueError(f"mpc.horizon and mpc.max_iter must be >= 1, got {self.horizon}, {self.max_iter}")
        if not 0 < self.thrust_min < self.thrust_max:
            raise ValueError(
                f"mpc thrust limits need 0 < thrust_min < thrust_max, got {self.thrust_min}, {self.thrust_max}"
            )


def _wrap(angle: torch.Tensor) -> torch.Tensor:
    return torch.remainder(angle + math.pi, 2 * math.pi) - math.pi


class LinearModel:
    """The MPC's discrete model, its condensed QP matrices and the LQR fallback (all float64)."""

    def __init__(self, p: MPCParams, g: float):
        a = np.zeros((8, 8))
        b = np.zeros((8, 3))
        a[0:3, 3:6] = np.eye(3)
        a[3:6, 3:6] = -np.diag(p.drag)
        a[3, 7] = g
        a[4, 6] = -g
        a[6, 6] = -1 / p.roll_time_constant
        a[7, 7] = -1 / p.pitch_time_constant
        b[5, 2] = 1.0
        b[6, 0] = p.roll_gain / p.roll_time_constant
        b[7, 1] = p.pitch_gain / p.pitch_time_constant
        bd = np.zeros((8, 3))
        bd[3:6] = np.eye(3)
        # Exact zero-order hold of [A B Bd] over prediction_dt.
        m = np.zeros((14, 14))
        m[:8, :8], m[:8, 8:11], m[:8, 11:14] = a, b, bd
        e = scipy.linalg.expm(m * p.prediction_dt)
        self.A, self.B, self.Bd = e[:8, :8], e[:8, 8:11], e[:8, 11:14]
        q = np.diag([*p.q_position, *p.q_velocity, *p.q_attitude])
        r = np.diag(p.r_command)
        self.P = scipy.linalg.solve_discrete_are(self.A, self.B, q, r)  # terminal cost
        self.K = torch.from_numpy(np.linalg.solve(self.B.T @ self.P @ self.B + r, self.B.T @ self.P @ self.A))  # LQR
        self.drag_rate = torch.from_numpy(np.diag(a)[3:6].copy())  # -drag, per axis
        self._condense(p, q, r, np.diag(p.r_delta))
        lower = [-math.radians(p.roll_max_deg), -math.radians(p.pitch_max_deg), p.thrust_min - g]
        upper = [math.radians(p.roll_max_deg), math.radians(p.pitch_max_deg), p.thrust_max - g]
        self.lower, self.upper = torch.tensor(lower, dtype=torch.float64), torch.tensor(upper, dtype=torch.float64)

    def _condense(self, p: MPCParams, q, r, rd) -> None:
        """Eliminate the states: X = Sx x0 + Su U + Sd d over x_1..x_N, so the cost is
        1/2 U'H U + U'(linear' [x0, d, x_ss, u_ss, u_prev]) + const, with U the stacked inputs."""
        n, nx, nu = p.horizon, 8, 3
        sx = np.zeros((n * nx, nx))
        su = np.zeros((n * nx, n * nu))
        sd = np.zeros((n * nx, 3))
        power = np.eye(nx)
        for k in range(n):
            power_prev, power = power, self.A @ power
            sx[k * nx : (k + 1) * nx] = power
            sd[k * nx : (k + 1) * nx] = (sd[(k - 1) * nx : k * nx] if k else 0) + power_prev @ self.Bd
            for j in range(k + 1):
                su[k * nx : (k + 1) * nx, j * nu : (j + 1) * nu] = np.linalg.matrix_power(self.A, k - j) @ self.B
        qbar = scipy.linalg.block_diag(*([q] * (n - 1) + [self.P]))
        rbar = scipy.linalg.block_diag(*([r] * n))
        rdbar = scipy.linalg.block_diag(*([rd] * n))
        diff = np.eye(n * nu) - np.eye(n * nu, k=-nu)  # (D U)_k = u_k - u_{k-1}, u_{-1} from outside
        first = np.zeros((n * nu, nu))
        first[:nu] = np.eye(nu)
        tile_x = np.tile(np.eye(nx), (n, 1))
        tile_u = np.tile(np.eye(nu), (n, 1))
        self.H = 2 * (su.T @ qbar @ su + rbar + diff.T @ rdbar @ diff)
        # The linear term of every env in one product: [x0, d, x_ss, u_ss, u_prev] @ linear.
        blocks = (su.T @ qbar @ sx, su.T @ qbar @ sd, -su.T @ qbar @ tile_x, -rbar @ tile_u, -diff.T @ rdbar @ first)
        self.linear = torch.from_numpy(np.ascontiguousarray(2 * np.concatenate(blocks, 1).T))


class LinearMPC(Controller):
    def __init__(self, airframe: AirframeParams, dt: float, params: MPCParams | None = None):
        super().__init__(airframe, dt)
        self.params = p = params or MPCParams()
        self.model = LinearModel(p, self.gravity)
        self.max_thrust = 4 * airframe.motor_constant * airframe.max_rotor_speed**2 / self.mass  # m/s^2
        self.solves, self.fallbacks = 0, 0  # fallbacks: envs x solves flown by the LQR instead
        self._solver, self._n = None, 0
        self._factors = {"attitude": 1.0, "angular_rate": 1.0}

    # What a tuning grid may scale per env: the inner loop's attitude and rate gains (the QP's
    # weights are one Hessian shared by every env, so candidates for them cannot fly side by side)
    GAIN_GROUPS = ("attitude", "angular_rate")

    def scale_gains(self, **factors) -> LinearMPC:
        """Multiply the inner loop's gain groups (GAIN_GROUPS) by factors: floats, or (n,) tensors
        giving each of n envs its own. Returns self."""
        unknown = set(factors) - set(self.GAIN_GROUPS)
        if unknown:
            raise ValueError(f"mpc gain groups are {', '.join(self.GAIN_GROUPS)}, got {', '.join(sorted(unknown))}")
        for group, factor in factors.items():
            self._factors[group] = self._factors[group] * torch.as_tensor(factor, dtype=torch.float64)
        return self

    def reset(self) -> None:
        self._solver, self._n = None, 0

    def _start(self, n: int) -> None:
        """Per-env state and the block-diagonal QP of n envs (built once per batch size)."""
        f64 = torch.float64
        self._n, self._count = n, 0
        self._u_prev = torch.zeros(n, 3, dtype=f64)  # last linearised command (roll, pitch, u_z)
        self._held = torch.zeros(n, 4, dtype=f64)  # roll cmd, pitch cmd, yaw-rate cmd, thrust (m/s^2)
        self._disturbance = torch.zeros(n, 3, dtype=f64)
        self._integral = torch.zeros(n, 2, dtype=f64)
        m = self.model
        hess = sp.kron(sp.eye(n), sp.csc_matrix(np.triu(m.H)), format="csc")
        self._solver = osqp.OSQP()
        self._solver.setup(
            hess,
            np.zeros(n * m.H.shape[0]),
            sp.eye(n * m.H.shape[0], format="csc"),
            np.tile(m.lower.numpy(), n * self.params.horizon),
            np.tile(m.upper.numpy(), n * self.params.horizon),
            verbose=False,
            warm_starting=True,
            polishing=False,
            eps_abs=1e-4,
            eps_rel=1e-4,
            max_iter=self.params.max_iter,
            check_termination=5,  # warm starts converge in a few iterations: check often
        )

    def _steady_state(self, goal: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(x_ss, u_ss): hover at the goal with the estimated disturbance cancelled."""
        p, g, d = self.params, self.gravity, self._disturbance
        roll, pitch = d[:, 1] / g, -d[:, 0] / g
        x_ss = torch.cat((goal, torch.zeros_like(goal), roll[:, None], pitch[:, None]), -1)
        u_ss = torch.stack((roll / p.roll_gain, pitch / p.pitch_gain, -d[:, 2]), -1)
        return x_ss, u_ss

    def _solve(self, x0: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """(n, 3) first input of the optimal sequence (LQR for envs where OSQP failed), within limits."""
        m, n = self.model, x0.shape[0]
        x_ss, u_ss = self._steady_state(goal)
        lin = torch.cat((x0, self._disturbance, x_ss, u_ss, self._u_prev), -1) @ m.linear
        self._solver.update(q=lin.reshape(-1).numpy())
        result = self._solver.solve(raise_error=False)
        self.solves += 1
        lqr = u_ss + (x_ss - x0) @ m.K.T
        if result.info.status_val in _USABLE and result.x is not None:
            u = torch.from_numpy(np.asarray(result.x)).reshape(n, -1)[:, :3]
            bad = ~torch.isfinite(u).all(-1)
        else:
            u, bad = lqr, torch.ones(n, dtype=torch.bool)
        u = torch.where(bad[:, None], lqr, u)
        self.fallbacks += int(bad.sum())
        return torch.maximum(torch.minimum(u, m.upper), m.lower)

    def command(self, odo: Odometry, goal: torch.Tensor) -> torch.Tensor:
        n, p, g = goal.shape[0], self.params, self.gravity
        if self._n != n:
            self._start(n)
        roll, pitch, yaw = odo.rpy.unbind(-1)
        # Solve at rate_hz on average whatever the control rate (every 2nd or 3rd step at 250 Hz).
        ticks = self._count * self.dt * p.rate_hz
        if self._count == 0 or math.floor(ticks + 1e-9) > math.floor(ticks - self.dt * p.rate_hz + 1e-9):
            cy, sy = yaw.cos(), yaw.sin()
            att = torch.stack((cy * roll - sy * pitch, sy * roll + cy * pitch), -1)  # yaw-aligned frame
            if p.offset_free:
                model_acc = odo.velocity * self.model.drag_rate + torch.stack(
                    (g * att[:, 1], -g * att[:, 0], self._u_prev[:, 2]), -1
                )
                rate = min(1.0, 1.0 / (p.rate_hz * p.disturbance_time_constant))
                self._disturbance += rate * (odo.acceleration - model_acc - self._disturbance)
                self._disturbance.clamp_(-p.disturbance_max, p.disturbance_max)
            x0 = torch.cat((odo.position, odo.velocity, att), -1)
            u = self._solve(x0, goal)
            self._u_prev = u
            thrust = ((u[:, 2] + g) / (roll.cos() * pitch.cos()).clamp_min(1e-3)).clamp_max(self.max_thrust)
            ux, uy = u[:, 1] * g / thrust, u[:, 0] * g / thrust  # back to the body's yaw frame
            yaw_error = torch.zeros_like(yaw) if p.yaw is None else _wrap(p.yaw - yaw)
            yaw_rate = (p.k_yaw * yaw_error).clamp(-math.radians(p.yaw_rate_max_deg), math.radians(p.yaw_rate_max_deg))
            self._held = torch.stack((ux * sy + uy * cy, ux * cy - uy * sy, yaw_rate, thrust), -1)
        self._count += 1
        return self._attitude_loop(odo, self._held)

    def _attitude_loop(self, odo: Odometry, held: torch.Tensor) -> torch.Tensor:
        p = self.params
        w = odo.angular_velocity
        err = held[:, 0:2] - odo.rpy[:, 0:2]
        self._integral = (self._integral + err * (self.dt / 0.01)).clamp(-p.att_integrator_max, p.att_integrator_max)
        integral = p.att_integrator_gain * self._integral
        k_att, k_rate = self._factors["attitude"], self._factors["angular_rate"]
        alpha = torch.stack(
            (
                k_att * p.att_roll_gain * err[:, 0] - k_rate * p.att_p_gain * w[:, 0] + integral[:, 0],
                k_att * p.att_pitch_gain * err[:, 1] - k_rate * p.att_q_gain * w[:, 1] + integral[:, 1],
                k_rate * p.att_r_gain * (held[:, 2] - w[:, 2]),
            ),
            -1,
        )
        torque = self.inertia * alpha + self.gyroscopic(w)
        return self.mixer(self.mass * held[:, 3], torque)
