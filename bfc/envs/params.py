"""The airframe (by default the AscTec Hummingbird of RotorS, rotors_description/urdf/hummingbird.xacro)
and the task's parameters.

One dataclass per concern, so a config can override any value (`env.airframe.*`); the per-episode
randomisation of some of them is `RandomizeParams`. The task's parameters (reward, termination,
starts, randomisation) are here too: plain dataclasses that check their values, so a config is
checked without importing torch or MuJoCo (a bad value on the command line fails at once).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

from bfc.checks import check as _check
from bfc.checks import finite

GOAL = (0.0, 0.0, 1.5)  # m: the paper's hover goal, every flight's and training's default
REFERENCE_PHYSICS_DT = 0.002  # s: the simulator every evaluation flies (training may step coarser)


def as_params(cls, value, **changes):
    """`value` as a `cls` params dataclass (None: the defaults, a mapping: its fields), with
    `changes` to some of its fields; an unknown field fails in one line naming the allowed ones."""
    if value is None and not changes:
        return cls()
    if isinstance(value, cls) and not changes:
        return value
    if isinstance(value, cls):
        value = {f.name: getattr(value, f.name) for f in fields(cls)}
    try:
        return cls(**{**dict(value or {}), **changes})
    except TypeError as err:
        allowed = ", ".join(f.name for f in fields(cls))
        raise ValueError(f"{cls.__name__}: {err}; allowed keys: {allowed}") from None


def params_from(cls, section, **changes):
    """A `cls` from the fields of a config section (a mapping or a dataclass; keys `cls` does
    not have are left out: a schema section extends its params with run-level keys) and `changes`."""
    get = section.get if hasattr(section, "get") else lambda name, default: getattr(section, name, default)
    missing = object()
    values = {f.name: get(f.name, missing) for f in fields(cls)}
    return as_params(cls, {k: v for k, v in values.items() if v is not missing}, **changes)


# Rotor layouts: the unit direction of each rotor from the centre, in bfc's motor order (counter-
# clockwise seen from above). "+": 0 front (+x), 1 left (+y), 2 back, 3 right. "x": the "+" turned
# 45 deg: 0 front-left, 1 back-left, 2 back-right, 3 front-right.
_D = math.sqrt(0.5)
LAYOUTS = {
    "+": ((1.0, 0.0), (0.0, 1.0), (-1.0, 0.0), (0.0, -1.0)),
    "x": ((_D, _D), (-_D, _D), (-_D, -_D), (_D, -_D)),
}
_PLACES = {
    "+": ("front (+x)", "left (+y)", "back (-x)", "right (-y)"),
    "x": ("front-left (+x +y)", "back-left (-x +y)", "back-right (-x -y)", "front-right (+x -y)"),
}
_TRIPLES = ("inertia", "hull_half_size")


@dataclass
class AirframeParams:
    """A quadrotor as data (the defaults: the AscTec Hummingbird of RotorS). The MuJoCo model,
    the motor model, the policy's hover speed and thrust map, the classical controllers' mixer and
    RotorPy's vehicle are all built from it; conf/env/airframe/ has the built-ins (docs/airframes.md)."""

    name: str = "hummingbird"  # a label: a built-in's name (conf/env/airframe/), a user file's stem
    body_mass: float = 0.68  # kg, base link only
    rotor_mass: float = 0.009  # kg, each of 4
    imu_mass: float = 0.015  # kg
    inertia: tuple[float, float, float] = (0.007, 0.007, 0.012)  # base link, kg m^2
    arm_length: float = 0.17  # m, centre to each rotor's axis
    rotor_height: float = 0.01  # m above the body centre
    motor_constant: float = 8.54858e-06  # k_f: thrust F = k_f w^2 (N, w in rad/s)
    moment_constant: float = 0.016  # yaw moment M = 0.016 F, opposing the rotor's spin
    max_rotor_speed: float = 838.0  # rad/s
    time_constant_up: float = 0.0125  # s, first-order motor lag when speeding up
    time_constant_down: float = 0.025  # s, when slowing down
    rotor_drag_coefficient: float = 8.06428e-05  # drag = -|w| c v_perp (per rotor)
    rolling_moment_coefficient: float = 1e-06  # moment = -|w| c v_perp (per rotor)
    gravity: float = 9.81  # m/s^2
    layout: str = "+"  # "+" (rotor 0 at the front) or "x" (rotor 0 front-left), LAYOUTS
    # each rotor's spin in motor order: 1 clockwise seen from above (its reaction torque turns the
    # body counter-clockwise, +z), -1 counter-clockwise
    rotor_spins: tuple[float, float, float, float] = (1.0, -1.0, 1.0, -1.0)
    min_rotor_speed: float = 0.0  # rad/s: the slowest a spinning motor turns (its ESC's idle)
    # the collision box (m): half its length, width and height; its bottom rests on the floor
    hull_half_size: tuple[float, float, float] = (0.2, 0.2, 0.04)

    def __post_init__(self) -> None:
        _check(isinstance(self.name, str) and self.name != "", "env.airframe.name", "a non-empty string", self.name)
        _check(self.layout in LAYOUTS, "env.airframe.layout", " or ".join(repr(k) for k in LAYOUTS), self.layout)
        spins = tuple(self.rotor_spins) if isinstance(self.rotor_spins, (tuple, list)) else ()
        _check(
            len(spins) == 4 and all(v in (1, -1) for v in spins) and spins[0] == spins[2] == -spins[1] == -spins[3],
            "env.airframe.rotor_spins",
            "4 spins of +1 (clockwise) and -1, opposite rotors alike and neighbours opposed, e.g. [1, -1, 1, -1]",
            self.rotor_spins,
        )
        self.rotor_spins = tuple(float(v) for v in spins)
        for f in fields(self):
            if f.name in ("name", "layout", "rotor_spins"):
                continue
            value = getattr(self, f.name)
            values = value if isinstance(value, (tuple, list)) else (value,)
            if f.name in _TRIPLES:
                _check(len(values) == 3, f"env.airframe.{f.name}", "3 numbers (x, y, z)", value)
            for v in values:
                ok = finite(v) and v >= 0
                _check(ok, f"env.airframe.{f.name}", "finite and >= 0", value)
        positive = ("body_mass", "motor_constant", "max_rotor_speed", "time_constant_up", "time_constant_down")
        for name in positive:
            _check(getattr(self, name) > 0, f"env.airframe.{name}", "> 0", getattr(self, name))
        _check(min(self.hull_half_size) > 0, "env.airframe.hull_half_size", "3 sizes > 0", self.hull_half_size)
        self.inertia = tuple(float(v) for v in self.inertia)
        ixx, iyy, izz = self.inertia
        _check(
            min(self.inertia) > 0 and ixx + iyy >= izz and iyy + izz >= ixx and izz + ixx >= iyy,
            "env.airframe.inertia",
            "a rigid body's (Ixx, Iyy, Izz) > 0, each at most the sum of the other two (a flat frame: Izz = Ixx + Iyy)",
            list(self.inertia),
        )
        self.hull_half_size = tuple(float(v) for v in self.hull_half_size)
        _check(
            self.hover_speed < self.max_rotor_speed,
            "env.airframe.max_rotor_speed",
            f"above the hover speed {self.hover_speed:.1f} rad/s (four rotors at full speed must lift the airframe)",
            self.max_rotor_speed,
        )
        _check(
            self.min_rotor_speed < self.hover_speed,
            "env.airframe.min_rotor_speed",
            f"below the hover speed {self.hover_speed:.1f} rad/s",
            self.min_rotor_speed,
        )

    @property
    def total_mass(self) -> float:
        return self.body_mass + 4 * self.rotor_mass + self.imu_mass

    @property
    def weight(self) -> float:
        """N: what four rotors carry in a hover."""
        return self.total_mass * self.gravity

    @property
    def rigid_inertia(self) -> tuple[float, float, float]:
        """Inertia of the whole rigid body (kg m^2): the base link plus the rotors as point masses
        at the arm tips (what MuJoCo integrates; controllers use it for J alpha). The same for both
        layouts: four rotors at radius L add 2 m L^2 about x and y and 4 m L^2 about z."""
        arm = self.rotor_mass * self.arm_length**2
        ixx, iyy, izz = self.inertia
        return (ixx + 2 * arm, iyy + 2 * arm, izz + 4 * arm)

    def mass_gain(self, body_mass_scale):
        """The gain on the body force that flies this airframe with its body_mass x `body_mass_scale`
        (a number or an array): m / m', the rotors and IMU unchanged."""
        return self.total_mass / (self.total_mass + self.body_mass * (body_mass_scale - 1))

    @property
    def thrust_to_weight(self) -> float:
        """Four rotors' full thrust over the weight: (max_rotor_speed / hover_speed)^2."""
        return (self.max_rotor_speed / self.hover_speed) ** 2

    @property
    def hover_speed(self) -> float:
        """Rotor speed (rad/s) at which four rotors carry the weight: sqrt(m g / (4 k_f))."""
        return math.sqrt(self.total_mass * self.gravity / (4 * self.motor_constant))

    @property
    def rotor_positions(self) -> tuple[tuple[float, float, float], ...]:
        """Each rotor's (x, y, z) in the body frame (m), motor order."""
        return tuple((dx * self.arm_length, dy * self.arm_length, self.rotor_height) for dx, dy in LAYOUTS[self.layout])

    @property
    def ground_height(self) -> float:
        """The centre's height when resting level on the floor (m): the hull's half height."""
        return self.hull_half_size[2]

    def motor_order(self) -> str:
        """Where each motor of a motor-speed vector sits and how it spins, for docs and exports."""
        spins = ["CW" if s > 0 else "CCW" for s in self.rotor_spins]
        places = _PLACES[self.layout]
        return ", ".join(f"{i} {place} {spin}" for i, (place, spin) in enumerate(zip(places, spins, strict=True)))

    def reflections(self) -> tuple[tuple[int, int, tuple[int, int, int, int]], ...]:
        """The airframe's symmetries that keep z: (sx, sy, motors) for each S = diag(sx, sy, 1)
        among the mirrors x -> -x and y -> -y and the half turn (both) that maps every rotor onto
        a rotor spinning as the image of its spin (a mirror reverses it); `motors[j]` is the motor
        whose image sits at motor j. An "x" has all three, a "+" the half turn only (its mirrors
        are the diagonals). The inertia is diagonal, so S keeps it. For the mirror loss
        (bfc.training.mirror): the same physics seen in a mirror."""
        found = []
        for sx, sy in ((-1, 1), (1, -1), (-1, -1)):
            motors = []
            for x, y, _ in self.rotor_positions:
                image = [
                    j
                    for j, (xj, yj, _) in enumerate(self.rotor_positions)
                    if abs(xj - sx * x) < 1e-9 and abs(yj - sy * y) < 1e-9
                ]
                motors.append(image[0] if image else None)
            spins = self.rotor_spins
            if None not in motors and all(spins[j] == sx * sy * spins[i] for i, j in enumerate(motors)):
                found.append((sx, sy, tuple(motors)))
        return tuple(found)

    def torque_rows(self) -> tuple[tuple[float, float, float], ...]:
        """Per rotor, the body torque (x, y, z) one newton of its thrust makes: r x F = (y, -x, 0)
        and the reaction yaw moment spin * moment_constant."""
        return tuple(
            (y, -x, self.moment_constant * s)
            for (x, y, _), s in zip(self.rotor_positions, self.rotor_spins, strict=True)
        )


# The default airframe: what the evaluation rows' newtons and Lee's published gains are given for
HUMMINGBIRD = AirframeParams()


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


FLOOR_CONTACT = 0.005  # m: the hull's lowest point below this height touches the floor


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

    @property
    def cos_ground_tilt(self) -> float:
        return math.cos(math.radians(self.ground_tilt_deg))

    def crashed(self, position, quaternion, cos_tilt, prev_vz, hull):
        """The crash rule, written once for QuadrotorEnv (NumPy) and RotorPy (torch): builtin abs()
        and operators work on both, with the same float ops in the same order. position (px, py, pz),
        quaternion (w, x, y, z): per-env arrays; cos_tilt = 1 - 2 (x^2 + y^2); prev_vz: the vertical
        velocity before the step; hull: the airframe's hull_half_size."""
        px, py, pz = position
        w, x, y, z = quaternion
        hx, hy, hz = hull
        # the collision box's lowest point: is the drone touching the floor?
        lowest = pz - (hx * abs(2 * (x * z - w * y)) + hy * abs(2 * (y * z + w * x)) + hz * abs(cos_tilt))
        touching = lowest < FLOOR_CONTACT
        tipped = cos_tilt < self.cos_ground_tilt
        hard = prev_vz < -self.crash_speed
        outside = (abs(px) > self.box_xy) | (abs(py) > self.box_xy) | (pz > self.box_z)
        return (touching & (tipped | hard)) | outside


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
    # a drawn airframe weaker than this (full thrust / weight) gets a larger motor constant until it
    # reaches it: wide mass and k_f ranges without bodies that cannot lift themselves (0: off)
    min_thrust_to_weight: float = 0.0

    def __post_init__(self) -> None:
        for name in ("external_force", "min_thrust_to_weight"):
            v = getattr(self, name)
            _check(finite(v) and v >= 0, f"env.randomize.{name}", ">= 0", v)
            setattr(self, name, float(v))
        for name in AIRFRAME_RANGES:
            r = getattr(self, name)
            ok = isinstance(r, (tuple, list)) and len(r) == 2 and all(finite(x) for x in r) and 0 < r[0] <= r[1]
            _check(ok, f"env.randomize.{name}", "[low, high] multipliers with 0 < low <= high", r)
            setattr(self, name, (float(r[0]), float(r[1])))

    def active(self, name: str) -> bool:
        low, high = getattr(self, name)
        return not (low == high == 1.0)


AIRFRAME_RANGES = ("mass", "inertia", "motor_constant", "motor_lag")


START_MOTORS = ("rest", "hover")


@dataclass
class EnvParams:
    """What one `QuadrotorEnv` flies, beside its batch and threads: the control rate and MuJoCo's
    step, the episode, the goal, the motors at release, the airframe and the task's parameters.
    The config's `env` section extends it (bfc.config.EnvConfig), so each default is written once."""

    control_hz: float = 100.0
    # MuJoCo's step (s); None: one step per control step
    physics_dt: float | None = REFERENCE_PHYSICS_DT
    episode_seconds: float = 5.0
    goal: tuple[float, float, float] = GOAL
    start_motors: str = "rest"  # rest | hover: the rotors at release
    airframe: AirframeParams = field(default_factory=AirframeParams)
    reward: RewardParams = field(default_factory=RewardParams)
    termination: TerminationParams = field(default_factory=TerminationParams)
    start: StartParams = field(default_factory=StartParams)
    randomize: RandomizeParams = field(default_factory=RandomizeParams)

    def __post_init__(self) -> None:
        _check(_positive(self.control_hz), "env.control_hz", "> 0", self.control_hz)
        if self.physics_dt is not None:
            allowed = "> 0 (or null: one step per control step)"
            _check(_positive(self.physics_dt), "env.physics_dt", allowed, self.physics_dt)
            substeps = self.substeps
            _check(
                substeps >= 1 and abs(substeps * self.physics_dt * self.control_hz - 1.0) < 1e-6,
                "env.control_hz",
                f"such that 1/control_hz is a whole number of physics steps of {self.physics_dt} s",
                self.control_hz,
            )
        _check(_positive(self.episode_seconds), "env.episode_seconds", "> 0", self.episode_seconds)
        goal = tuple(self.goal) if isinstance(self.goal, (tuple, list)) else ()
        ok = len(goal) == 3 and all(finite(v) for v in goal)
        _check(ok, "env.goal", "3 finite numbers (x, y, z)", self.goal)
        self.goal = tuple(float(v) for v in goal)
        _check(self.start_motors in START_MOTORS, "env.start_motors", "'rest' or 'hover'", self.start_motors)
        self.airframe = as_params(AirframeParams, self.airframe)
        self.reward = as_params(RewardParams, self.reward)
        self.termination = as_params(TerminationParams, self.termination)
        self.start = as_params(StartParams, self.start)
        self.randomize = as_params(RandomizeParams, self.randomize)

    @property
    def physics_step(self) -> float:
        """MuJoCo's step (s): `physics_dt`, or one step per control step when it is None."""
        return float(self.physics_dt) if self.physics_dt is not None else 1.0 / float(self.control_hz)

    @property
    def substeps(self) -> int:
        """MuJoCo steps per control step."""
        return round(1.0 / (float(self.control_hz) * self.physics_step))


JD_SCHEDULES = ("linear", "cosine", "constant")


@dataclass
class JDParams:
    """The Jumping Distribution's starts (paper sec. 4.1; bfc.transforms.jd), the paper's values by
    default: in the air with probability p(t), falling from p0 to p_end over decay_frames, at an
    attitude within +-60 deg, at rest. Ranges are [low, high] in m, deg, m/s and deg/s. Here, beside
    the task's own starts, so that the config (bfc.config.JDConfig) extends it without torch."""

    p0: float = 1.0
    p_end: float = 0.0
    decay_frames: int | None = 10_000_000  # None: the run's collector.total_frames (bfc.config)
    schedule: str = "linear"  # linear | cosine | constant
    z_range: tuple[float, float] = (0.5, 3.0)
    roll_range: tuple[float, float] = (-60.0, 60.0)
    pitch_range: tuple[float, float] = (-60.0, 60.0)
    yaw_range: tuple[float, float] = (-180.0, 180.0)
    velocity_range: tuple[float, float] = (0.0, 0.0)  # per axis
    angular_velocity_range: tuple[float, float] = (0.0, 0.0)  # per axis
    inverted_share: float = 0.0  # of the right-way-up air starts, turned upside down
    inverted_at_rest: float = 0.0  # of those upside-down starts, released at rest
    inverted_spread: float = 1.0  # their roll, pitch x this before the turn: nearer 180 deg

    def __post_init__(self) -> None:
        for name in ("p0", "p_end", "inverted_share", "inverted_at_rest"):
            v = getattr(self, name)
            _check(finite(v) and 0.0 <= v <= 1.0, f"jd.{name}", "in [0, 1]", v)
            setattr(self, name, float(v))
        v = self.inverted_spread
        _check(finite(v) and 0.0 < v <= 1.0, "jd.inverted_spread", "in (0, 1]", v)
        self.inverted_spread = float(v)
        v = self.decay_frames
        ok = v is None or (isinstance(v, int) and not isinstance(v, bool) and v >= 0)
        _check(ok, "jd.decay_frames", "an integer >= 0 (or null: the run's total frames)", v)
        _check(self.schedule in JD_SCHEDULES, "jd.schedule", f"one of {JD_SCHEDULES}", self.schedule)
        for name in ("z_range", "roll_range", "pitch_range", "yaw_range", "velocity_range", "angular_velocity_range"):
            r = getattr(self, name)
            ok = isinstance(r, (tuple, list)) and len(r) == 2 and all(finite(x) for x in r) and r[0] <= r[1]
            _check(ok, f"jd.{name}", "a pair [low, high] with low <= high", r)
            setattr(self, name, (float(r[0]), float(r[1])))
        _check(self.z_range[0] > 0, "jd.z_range", "above the ground (low > 0)", self.z_range)


def _positive(v) -> bool:
    return finite(v) and v > 0
