"""AscTec Hummingbird parameters as in RotorS (rotors_description/urdf/hummingbird.xacro).

One dataclass, so a config can override any of them (`env.airframe.*`); the per-episode
randomisation of some of them is `RandomizeParams`. The task's parameters (reward, termination,
starts, randomisation) are here too: plain dataclasses that check their values, so a config is
checked without importing torch or MuJoCo (a bad value on the command line fails at once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

from bfc.checks import check as _check

GOAL = (0.0, 0.0, 1.5)  # m: the paper's hover goal, every flight's and training's default


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


REWARD_KINDS = ("bfc", "paper")


@dataclass
class RewardParams:
    """Shaped reward: closer and more level is better (weights per term; see docs/env.md).

    P = position |p - g| + tilt (1 - cos tilt) + yaw (1 - cos yaw) + velocity |v|^2
        + angular_velocity |w|^2 + yaw_rate w_z^2 + action |a|^2,      a = (command - hover) / hover
    r = scale * (alive exp(-P / alive) + precision exp(-|p - g|^2 / precision_radius^2))
    and a crash adds -scale * crash_penalty. The step reward is positive everywhere, so staying
    alive always beats crashing (with `alive - P` it is negative far from the goal, and PPO
    learns to crash early to stop paying), and it still grows with every error that shrinks.

    kind="paper" is the paper's sec. 6.4 instead (position and angle terms, a terminal penalty):
    r = -scale * (position |p - g| + tilt (|roll| + |pitch|) + yaw |yaw|), and a crash (leaving
    the allowed box, hitting the floor) adds -scale * crash_penalty; the other weights are unused.
    """

    kind: str = "bfc"  # bfc | paper (conf/reward/paper.yaml)
    alive: float = 1.0
    position: float = 1.0
    tilt: float = 0.5
    yaw: float = 0.0  # yaw is free: with 0.1 policies flip over to "turn round" from yaw +-180 (docs)
    velocity: float = 0.05
    angular_velocity: float = 0.005
    yaw_rate: float = 0.05  # heading is free, spinning is not: without it hovers spin up (docs/env.md)
    action: float = 0.05
    precision: float = 1.0
    precision_radius: float = 0.1
    crash_penalty: float = 10.0
    scale: float = 0.01

    def __post_init__(self) -> None:
        _check(self.kind in REWARD_KINDS, "env.reward.kind", " or ".join(REWARD_KINDS), self.kind)
        for f in fields(self)[1:]:
            v = getattr(self, f.name)
            _check(isinstance(v, (int, float)) and math.isfinite(v), f"env.reward.{f.name}", "a finite number", v)
        _check(self.precision_radius > 0, "env.reward.precision_radius", "> 0", self.precision_radius)
        _check(self.alive > 0, "env.reward.alive", "> 0", self.alive)


@dataclass
class TerminationParams:
    """When a flight is a crash (terminated). Resting level on the floor is never one."""

    box_xy: float = 5.0  # |x| or |y| beyond this (m) leaves the allowed box
    box_z: float = 6.0  # z above this (m) leaves the allowed box
    ground_tilt_deg: float = 60.0  # touching the floor tilted more than this = tipped over
    crash_speed: float = 2.0  # touching the floor faster than this (m/s, downwards) = hit hard

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            _check(isinstance(v, (int, float)) and v > 0, f"env.termination.{f.name}", "> 0", v)


@dataclass
class StartParams:
    """The task's start distribution D: on the floor at a random (x, y), level, at rest."""

    xy_range: float = 2.0  # x, y uniform in [-xy_range, xy_range]
    yaw_range_deg: float = 180.0  # yaw uniform in [-yaw_range, yaw_range]

    def __post_init__(self) -> None:
        _check(self.xy_range >= 0, "env.start.xy_range", ">= 0", self.xy_range)
        _check(0 <= self.yaw_range_deg <= 180, "env.start.yaw_range_deg", "in [0, 180]", self.yaw_range_deg)


@dataclass
class RandomizeParams:
    """Per-episode randomisation of the world (domain randomisation), drawn at every reset from
    the env's generator; all off by default (then nothing is drawn and runs are unchanged).

    Airframe ranges are multipliers [low, high] of the nominal value, uniform per episode, each a
    per-env column of the NumPy motor model: motor constant and motor lag directly, mass and
    inertia as gains on the body wrench (exact for the rigid body in flight; floor contact acts on
    the nominal mass).
    """

    external_force: float = 0.0  # N: a constant horizontal force, random direction, size uniform in [0, this]
    mass: tuple[float, float] = (1.0, 1.0)  # x body_mass
    inertia: tuple[float, float] = (1.0, 1.0)  # x the base link's inertia (all three axes)
    motor_constant: tuple[float, float] = (1.0, 1.0)  # x k_f (thrust per speed squared)
    motor_lag: tuple[float, float] = (1.0, 1.0)  # x both motor time constants

    def __post_init__(self) -> None:
        v = self.external_force
        _check(isinstance(v, (int, float)) and math.isfinite(v) and v >= 0, "env.randomize.external_force", ">= 0", v)
        for name in AIRFRAME_RANGES:
            r = getattr(self, name)
            ok = (
                isinstance(r, (tuple, list))
                and len(r) == 2
                and all(isinstance(x, (int, float)) and math.isfinite(x) for x in r)
                and 0 < r[0] <= r[1]
            )
            _check(ok, f"env.randomize.{name}", "[low, high] multipliers with 0 < low <= high", r)
            setattr(self, name, (float(r[0]), float(r[1])))

    def active(self, name: str) -> bool:
        low, high = getattr(self, name)
        return not (low == high == 1.0)


AIRFRAME_RANGES = ("mass", "inertia", "motor_constant", "motor_lag")
