"""Lee's geometric position controller (Lee, Leok, McClamroch 2010) as RotorS flies it.

Gains are RotorS's lee_controller_hummingbird.yaml. As in RotorS the position and velocity gains
are divided by the mass (they act as forces), and the attitude and rate gains act as torques
(RotorS divides them by the inertia to get angular accelerations, then multiplies back).
The protocol judges position only and the BFC policy is yaw-free, so by default the controller
holds whatever heading it has (desired yaw = current yaw, desired body rate 0); `yaw=0.0` asks for
a fixed heading instead, which from yaw +-180 deg starts puts Lee's attitude error near its
singularity (docs/controllers.md has the measured difference).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from bfc.controllers.base import Controller, Odometry
from bfc.envs.params import HUMMINGBIRD, AirframeParams


@dataclass
class LeeGains:
    position: tuple[float, float, float] = (4.0, 4.0, 4.0)
    velocity: tuple[float, float, float] = (2.2, 2.2, 2.2)
    attitude: tuple[float, float, float] = (0.7, 0.7, 0.035)
    angular_rate: tuple[float, float, float] = (0.1, 0.1, 0.025)
    yaw: float | None = None  # desired heading (rad); None: hold the current one (the task is yaw-free)
    # Beyond RotorS: an integral of the position error (N per m s), which removes a steady offset
    # (a heavier body, weaker motors, wind); 0 = RotorS's controller. `lee_i` sets it.
    integral: tuple[float, float, float] = (0.0, 0.0, 0.0)
    integral_max: float = 3.0  # m s per axis: anti-windup clamp of the integrated error

    def __post_init__(self) -> None:
        if self.integral_max <= 0:
            raise ValueError(f"lee.integral_max must be > 0, got {self.integral_max!r}")
        for name in ("position", "velocity", "attitude", "angular_rate", "integral"):
            v = getattr(self, name)
            if len(v) != 3 or any(g < 0 for g in v):
                raise ValueError(f"lee.{name} must be 3 gains >= 0, got {v!r}")


def _vee(m: torch.Tensor) -> torch.Tensor:
    """(n, 3, 3) skew-symmetric -> (n, 3)."""
    return torch.stack((m[:, 2, 1], m[:, 0, 2], m[:, 1, 0]), -1)


class LeeController(Controller):
    """Lee's controller for `airframe`. Its gains (LeeGains) are the Hummingbird's; on another
    airframe the position, velocity and integral gains scale with the mass and the attitude and
    rate gains with the inertia (per axis), so that the closed loop asks the same accelerations of
    every airframe per unit of error (RotorS's own normalisation; 1 on the Hummingbird)."""

    def __init__(self, airframe: AirframeParams, dt: float, gains: LeeGains | None = None):
        super().__init__(airframe, dt)
        self.gains = gains or LeeGains()
        f64 = torch.float64
        mass = airframe.total_mass / HUMMINGBIRD.total_mass
        inertia = self.inertia / torch.tensor(HUMMINGBIRD.rigid_inertia, dtype=f64)
        self.kp = torch.tensor(self.gains.position, dtype=f64) * mass
        self.kv = torch.tensor(self.gains.velocity, dtype=f64) * mass
        self.kr = torch.tensor(self.gains.attitude, dtype=f64) * inertia
        self.kw = torch.tensor(self.gains.angular_rate, dtype=f64) * inertia
        self.ki = torch.tensor(self.gains.integral, dtype=f64) * mass
        self._integral = None

    GAIN_GROUPS = ("position", "velocity", "attitude", "angular_rate")

    def scale_gains(self, **factors) -> LeeController:
        """Multiply the gain groups (GAIN_GROUPS) by factors: floats, or (n,) tensors giving each of
        n envs its own (a tuning grid flies its candidates side by side). Returns self."""
        unknown = set(factors) - set(self.GAIN_GROUPS)
        if unknown:
            raise ValueError(f"lee gain groups are {', '.join(self.GAIN_GROUPS)}, got {', '.join(sorted(unknown))}")
        attr = {"position": "kp", "velocity": "kv", "attitude": "kr", "angular_rate": "kw"}
        for group, factor in factors.items():
            f = torch.as_tensor(factor, dtype=torch.float64)
            setattr(self, attr[group], getattr(self, attr[group]) * (f.unsqueeze(-1) if f.ndim else f))
        return self

    def reset(self) -> None:
        self._integral = None

    def command(self, odo: Odometry, goal: torch.Tensor) -> torch.Tensor:
        n = goal.shape[0]
        e3 = torch.tensor([0.0, 0.0, 1.0], dtype=torch.float64)
        # Minus the desired acceleration (RotorS's sign convention): b3_des points along -acc.
        error = odo.position - goal
        force = self.kp * error + self.kv * odo.velocity
        if bool((self.ki > 0).any()):
            if self._integral is None or self._integral.shape[0] != n:
                self._integral = torch.zeros(n, 3, dtype=torch.float64)
            lim = self.gains.integral_max
            self._integral = (self._integral + error * self.dt).clamp(-lim, lim)
            force = force + self.ki * self._integral
        acc = force / self.mass - self.gravity * e3
        b3 = -acc / acc.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        yaw = odo.rpy[:, 2] if self.gains.yaw is None else torch.full((n,), self.gains.yaw, dtype=torch.float64)
        b1_heading = torch.stack((yaw.cos(), yaw.sin(), torch.zeros_like(yaw)), -1)
        b2 = torch.cross(b3, b1_heading, dim=-1)
        b2 = b2 / b2.norm(dim=-1, keepdim=True).clamp_min(1e-9)
        r_des = torch.stack((torch.cross(b2, b3, dim=-1), b2, b3), -1)
        r = odo.rotation
        e_r = 0.5 * _vee(r_des.transpose(1, 2) @ r - r.transpose(1, 2) @ r_des)
        w = odo.angular_velocity  # the rate error: the desired body rate is 0 (fixed heading)
        torque = -self.kr * e_r - self.kw * w + self.gyroscopic(w)
        thrust = -self.mass * (acc * r[:, :, 2]).sum(-1)
        return self.mixer(thrust, torque)


LEE_INTEGRAL_GAINS = (2.0, 2.0, 2.0)  # N / (m s): closes a 2 N offset (mass +30%) in a few seconds


def lee_with_integral(airframe: AirframeParams, dt: float) -> LeeController:
    """`controller=lee_i`: Lee with an integral of the position error (beyond RotorS)."""
    return LeeController(airframe, dt, LeeGains(integral=LEE_INTEGRAL_GAINS))
