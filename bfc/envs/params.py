"""AscTec Hummingbird parameters as in RotorS (rotors_description/urdf/hummingbird.xacro).

One dataclass, so a config can override any of them (`env.airframe.*`); the per-episode
randomisation of some of them is `RandomizeParams` in bfc/envs/quadrotor.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields


@dataclass
class AirframeParams:
    body_mass: float = 0.68  # kg, base link only
    rotor_mass: float = 0.009  # kg, each of 4
    imu_mass: float = 0.015  # kg
    inertia: tuple[float, float, float] = (0.007, 0.007, 0.012)  # base link, kg m^2
    arm_length: float = 0.17  # m, "+" layout
    rotor_height: float = 0.01  # m above the body centre
    motor_constant: float = 8.54858e-06  # k_f: thrust F = k_f w^2 (N, w in rad/s)
    moment_constant: float = 0.016  # yaw moment M = 0.016 F, opposing the rotor's spin
    max_rotor_speed: float = 838.0  # rad/s
    time_constant_up: float = 0.0125  # s, first-order motor lag when speeding up
    time_constant_down: float = 0.025  # s, when slowing down
    rotor_drag_coefficient: float = 8.06428e-05  # drag = -|w| c v_perp (per rotor)
    rolling_moment_coefficient: float = 1e-06  # moment = -|w| c v_perp (per rotor)
    gravity: float = 9.81  # m/s^2

    def __post_init__(self) -> None:
        for f in fields(self):
            value = getattr(self, f.name)
            values = value if isinstance(value, (tuple, list)) else (value,)
            if f.name == "inertia" and len(values) != 3:
                raise ValueError(f"airframe.inertia must have 3 entries (Ixx, Iyy, Izz), got {value!r}")
            for v in values:
                if not (isinstance(v, (int, float)) and math.isfinite(v) and v >= 0):
                    raise ValueError(f"airframe.{f.name} must be finite and >= 0, got {value!r}")
        positive = ("body_mass", "motor_constant", "max_rotor_speed", "time_constant_up", "time_constant_down")
        for name in positive:
            if getattr(self, name) <= 0:
                raise ValueError(f"airframe.{name} must be > 0, got {getattr(self, name)!r}")
        self.inertia = tuple(float(v) for v in self.inertia)

    @property
    def total_mass(self) -> float:
        return self.body_mass + 4 * self.rotor_mass + self.imu_mass

    @property
    def rigid_inertia(self) -> tuple[float, float, float]:
        """Inertia of the whole rigid body (kg m^2): the base link plus the rotors as point masses
        at the arm tips (what MuJoCo integrates; controllers use it for J alpha)."""
        arm = self.rotor_mass * self.arm_length**2
        ixx, iyy, izz = self.inertia
        return (ixx + 2 * arm, iyy + 2 * arm, izz + 4 * arm)

    @property
    def hover_speed(self) -> float:
        """Rotor speed (rad/s) at which four rotors carry the weight: sqrt(m g / (4 k_f))."""
        return math.sqrt(self.total_mass * self.gravity / (4 * self.motor_constant))


# Rotor layout and motor order (the order of every motor-speed vector in bfc):
# 0 front (+x) CW, 1 left (+y) CCW, 2 back (-x) CW, 3 right (-y) CCW.
ROTOR_DIRECTIONS = ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0))
# Reaction torque about +z per newton of thrust, in units of moment_constant: a CW rotor (seen
# from above) pushes the body counter-clockwise (+z), a CCW rotor clockwise (-z).
ROTOR_YAW_SIGNS = (1.0, -1.0, 1.0, -1.0)
