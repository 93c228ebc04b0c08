"""Named start sets and flight conditions beyond the paper's protocol (`CONDITIONS`: the rows of
`evaluate.py suite=robust`), and the robustness table.

Start sets (each (n, 12) in the `"start_state"` layout, x and y uniform in [-2, 2] m):
    protocol  the paper's: z 0.5-3 m, roll and pitch each +-60 deg, any yaw, at rest
    harsh     z 0.5-3 m, roll and pitch each +-85 deg, any yaw, released at up to 1 m/s in a random
              direction and spinning at up to 2 rad/s about each body axis
    any       a uniformly random attitude (upside down included), z 1.5-3 m, at rest
    ground    on the floor, level, any yaw, at rest (take-off)
    throw     thrown: any attitude (uniform), z 2-4 m, 5 m/s in a random horizontal direction
              tilted -20 to +45 deg from the horizontal, spinning at up to 5 rad/s (a random
              axis); flown with the motors at hover at release (`HARDWARE`)
Conditions (the protocol's starts; the flown body differs from the one the controller knows):
    mass +-30% (body_mass), motor constant +-20%, motor time constants x3, inertia x1.5, and a
    constant 1 N wind in a random horizontal direction per start.
What a flight computer adds (`HARDWARE`, the rows of `evaluate.py suite=hardware`): odometry 10-50
ms old, commands applied 10-20 ms late (whole control steps, rounded down: bfc.transforms.latency),
a state estimate with noise and a per-flight gyro bias (`ESTIMATOR_NOISE`), and the throw.

Every set is drawn from its own CPU generator seeded by (seed, set name), so the same seed gives
the same starts on every machine; seed 0 is the test set the docs report (TEST_SEED).
"""

from __future__ import annotations

import dataclasses
import math
import zlib
from dataclasses import dataclass, field

import torch

from bfc.envs import AirframeParams
from bfc.envs.params import HUMMINGBIRD
from bfc.envs.rotations import quat_to_euler
from bfc.evaluation.judge import judge
from bfc.evaluation.metrics import hover_error
from bfc.evaluation.protocol import TEST_SEED, protocol_starts


def _generator(name: str, seed: int) -> torch.Generator:
    return torch.Generator().manual_seed(int(seed) * 1_000_003 + zlib.crc32(name.encode()))


def _uniform(g, n, lo, hi) -> torch.Tensor:
    return lo + (hi - lo) * torch.rand(n, generator=g, dtype=torch.float64)


def harsh_starts(n: int = 100, seed: int = TEST_SEED) -> torch.Tensor:
    g = _generator("harsh", seed)
    deg = math.pi / 180
    s = torch.zeros(n, 12, dtype=torch.float64)
    s[:, 0], s[:, 1], s[:, 2] = _uniform(g, n, -2, 2), _uniform(g, n, -2, 2), _uniform(g, n, 0.5, 3.0)
    s[:, 3], s[:, 4], s[:, 5] = (
        _uniform(g, n, -85, 85) * deg,
        _uniform(g, n, -85, 85) * deg,
        _uniform(g, n, -180, 180) * deg,
    )
    direction = torch.randn(n, 3, generator=g, dtype=torch.float64)
    s[:, 6:9] = direction / direction.norm(dim=-1, keepdim=True) * _uniform(g, n, 0, 1).unsqueeze(-1)
    s[:, 9:12] = torch.stack([_uniform(g, n, -2, 2) for _ in range(3)], -1)
    return s.float()


def any_starts(n: int = 100, seed: int = TEST_SEED) -> torch.Tensor:
    g = _generator("any", seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)  # a normalised Gaussian: uniform on SO(3)
    q = q / q.norm(dim=-1, keepdim=True)
    s = torch.zeros(n, 12, dtype=torch.float64)
    s[:, 0], s[:, 1], s[:, 2] = _uniform(g, n, -2, 2), _uniform(g, n, -2, 2), _uniform(g, n, 1.5, 3.0)
    s[:, 3:6] = quat_to_euler(q)
    return s.float()


def ground_starts(n: int = 100, seed: int = TEST_SEED, airframe: AirframeParams | None = None) -> torch.Tensor:
    """Level and at rest on the floor (the airframe's resting height; the Hummingbird's by default)."""
    g = _generator("ground", seed)
    s = torch.zeros(n, 12, dtype=torch.float64)
    s[:, 0], s[:, 1] = _uniform(g, n, -2, 2), _uniform(g, n, -2, 2)
    s[:, 2] = (airframe or HUMMINGBIRD).ground_height
    s[:, 5] = _uniform(g, n, -math.pi, math.pi)
    return s.float()


def throw_starts(n: int = 100, seed: int = TEST_SEED) -> torch.Tensor:
    g = _generator("throw", seed)
    q = torch.randn(n, 4, generator=g, dtype=torch.float64)
    q = q / q.norm(dim=-1, keepdim=True)
    s = torch.zeros(n, 12, dtype=torch.float64)
    s[:, 0], s[:, 1], s[:, 2] = _uniform(g, n, -2, 2), _uniform(g, n, -2, 2), _uniform(g, n, 2.0, 4.0)
    s[:, 3:6] = quat_to_euler(q)
    heading = _uniform(g, n, -math.pi, math.pi)
    elevation = _uniform(g, n, -20, 45) * math.pi / 180
    s[:, 6], s[:, 7] = elevation.cos() * heading.cos(), elevation.cos() * heading.sin()
    s[:, 8] = elevation.sin()
    s[:, 6:9] *= THROW_SPEED
    axis = torch.randn(n, 3, generator=g, dtype=torch.float64)
    s[:, 9:12] = axis / axis.norm(dim=-1, keepdim=True) * _uniform(g, n, 0, THROW_SPIN).unsqueeze(-1)
    return s.float()


THROW_SPEED, THROW_SPIN = 5.0, 5.0  # m/s, rad/s
START_SETS = {
    "protocol": protocol_starts,
    "harsh": harsh_starts,
    "any": any_starts,
    "ground": ground_starts,
    "throw": throw_starts,
}


def start_set(name: str, n: int = 100, seed: int = TEST_SEED, airframe: AirframeParams | None = None) -> torch.Tensor:
    """The start set `name` (START_SETS) for `airframe`: a ground start rests at its own height."""
    if name not in START_SETS:
        raise ValueError(f"unknown start set {name!r}; available: {', '.join(START_SETS)}")
    return ground_starts(n, seed, airframe) if name == "ground" else START_SETS[name](n, seed)


def horizontal_wind(n: int, newtons: float = 1.0, seed: int = TEST_SEED) -> torch.Tensor:
    """(n, 3) a horizontal force of `newtons` in a random direction per start."""
    angle = _uniform(_generator("wind", seed), n, -math.pi, math.pi)
    return torch.stack((angle.cos(), angle.sin(), torch.zeros(n, dtype=torch.float64)), -1) * newtons


@dataclass
class Condition:
    """A flight condition: the starts it flies and what differs from the nominal world."""

    starts: str = "protocol"
    airframe: dict = field(default_factory=dict)  # multipliers of AirframeParams fields
    wind_newtons: float = 0.0  # on the Hummingbird; another airframe gets the same share of its weight
    observation_delay: float = 0.0  # s: the odometry the controller sees is this old
    action_delay: float = 0.0  # s: its commands reach the motors this late
    noise: dict | None = None  # a `noise` section: what the controller sees (the judge sees the truth)
    start_motors: str = "rest"  # or "hover": the motors spinning at hover at release

    def wind(self, airframe: AirframeParams | None = None) -> float:
        """N: the row's wind on `airframe`, the same share of its weight as on the Hummingbird."""
        return self.wind_newtons * ((airframe or HUMMINGBIRD).weight / HUMMINGBIRD.weight)

    def starts_for(self, n: int, seed: int, airframe: AirframeParams | None = None) -> torch.Tensor:
        return start_set(self.starts, n, seed, airframe)

    def world(self, airframe: AirframeParams, n: int, seed: int):
        """What the row flies on `airframe`: (its n starts, the wind per start (n, 3) N or None,
        the flown airframe's overrides or None)."""
        wind = horizontal_wind(n, self.wind(airframe), seed) if self.wind_newtons else None
        return self.starts_for(n, seed, airframe), wind, self.flown_airframe(airframe)

    def hardware(self) -> dict:
        """`fly`'s arguments for what the flight computer adds on this row (latency, noise, motors at release)."""
        out = {"observation_delay": self.observation_delay, "action_delay": self.action_delay}
        out["start_motors"] = self.start_motors
        if self.noise is not None:
            out["noise"] = self.noise
        return out

    def flown_airframe(self, nominal: AirframeParams | None = None) -> dict | None:
        """The AirframeParams overrides of the flown body (None: nominal)."""
        if not self.airframe:
            return None
        nominal = nominal or AirframeParams()
        out = {}
        for name, factor in self.airframe.items():
            value = getattr(nominal, name)
            out[name] = [v * factor for v in value] if isinstance(value, tuple) else value * factor
        return out


CONDITIONS = {
    "protocol": Condition(),
    "harsh": Condition("harsh"),
    "any": Condition("any"),
    "ground": Condition("ground"),
    "mass +30%": Condition(airframe={"body_mass": 1.3}),
    "mass -30%": Condition(airframe={"body_mass": 0.7}),
    "motor constant -20%": Condition(airframe={"motor_constant": 0.8}),
    "motor constant +20%": Condition(airframe={"motor_constant": 1.2}),
    "motor lag x3": Condition(airframe={"time_constant_up": 3.0, "time_constant_down": 3.0}),
    "inertia x1.5": Condition(airframe={"inertia": 1.5}),
    "wind 1 N": Condition(wind_newtons=1.0),  # the default's training wind (14% of the weight)
    "wind 2 N": Condition(wind_newtons=2.0),  # twice the training wind
}


# A state estimate as a flight computer's estimator gives it (per element of the odometry:
# position, velocity, acceleration, roll/pitch/yaw, body rates, angular acceleration): 2 cm, 5 cm/s,
# 0.2 m/s^2, 1 deg, 0.03 rad/s, 0.5 rad/s^2 of white noise, and a gyro bias of 0.02 rad/s (1.1
# deg/s) per axis and flight.
_DEG = math.pi / 180
ESTIMATOR_NOISE = {
    "kind": "gaussian",
    "std": [0.02] * 3 + [0.05] * 3 + [0.2] * 3 + [1.0 * _DEG] * 3 + [0.03] * 3 + [0.5] * 3,
    "bias": [0.0] * 12 + [0.02] * 3 + [0.0] * 3,
    "elements": "all",
}
HARDWARE = {
    "observation latency 10 ms": Condition(observation_delay=0.010),
    "observation latency 20 ms": Condition(observation_delay=0.020),
    "observation latency 30 ms": Condition(observation_delay=0.030),
    "observation latency 50 ms": Condition(observation_delay=0.050),
    "actuation latency 10 ms": Condition(action_delay=0.010),
    "actuation latency 20 ms": Condition(action_delay=0.020),
    "estimator noise, gyro bias": Condition(noise=ESTIMATOR_NOISE),
    "throw 5 m/s, any attitude": Condition("throw", start_motors="hover"),
}
SUITES = {"robust": CONDITIONS, "hardware": HARDWARE}  # evaluate.py suite=... -> its rows


def condition(name: str) -> Condition:
    """A row of suite=robust or suite=hardware by name."""
    for rows in SUITES.values():
        if name in rows:
            return rows[name]
    available = [n for rows in SUITES.values() for n in rows]
    raise ValueError(f"unknown condition {name!r}; available: {', '.join(available)}")


def fly_condition(
    controller,
    name: str,
    num_starts: int = 100,
    seed: int = TEST_SEED,
    seconds: float = 10.0,
    airframe: AirframeParams | None = None,
    **kw,
):
    """Fly `controller` (anything `fly` takes) under the named condition (a row of suite=robust or
    suite=hardware) on its airframe: a policy's own, else `airframe` (the Hummingbird by default)."""
    from bfc.evaluation.flying import airframe_of, fly

    c = condition(name)
    nominal = airframe_of(controller, airframe)
    starts, wind, flown = c.world(nominal, num_starts, seed)
    return fly(
        controller,
        starts,
        seconds=seconds,
        seed=seed,
        airframe=flown,
        external_force=wind,
        nominal=dataclasses.asdict(nominal),
        **c.hardware(),
        **kw,
    )


def score(flights, threshold: float = 0.10, hold_seconds: float = 1.0) -> dict:
    verdict = judge(flights, threshold, hold_seconds)
    return {
        "success_rate": verdict.success.float().mean().item(),
        "crashes": int((~flights.get("alive")[:, -1]).sum()),
        "hover_error_m": hover_error(flights, verdict.success),
    }


def robust_results(
    controllers: dict,
    names=None,
    num_starts: int = 100,
    seed: int = TEST_SEED,
    protocol=None,
    on_flights=None,
    fly_row=None,
    airframe: AirframeParams | None = None,
) -> dict:
    """{condition: {label: score}} for every controller (label -> anything `fly` takes) and condition,
    each on its airframe: a policy's own, else `airframe` (the Hummingbird by default).

    on_flights(condition, label, flights), if given, sees each flight set before it is dropped
    (evaluate.py's video=true keeps the poses of a few flights of each row); a dict it returns is
    added to that score. fly_row(controller, condition, num_starts, seed, seconds, airframe) flies a row
    (default `fly_condition`: MuJoCo; RotorPy passes its own)."""
    fly_row = fly_row or fly_condition
    seconds = protocol.seconds if protocol is not None else 10.0
    threshold = protocol.threshold if protocol is not None else 0.10
    hold = protocol.hold_seconds if protocol is not None else 1.0
    results = {}
    for name in CONDITIONS if names is None else names:
        results[name] = {}
        for label, c in controllers.items():
            flights = fly_row(c, name, num_starts, seed, seconds, airframe)
            extra = on_flights(name, label, flights) if on_flights is not None else None
            results[name][label] = {**score(flights, threshold, hold), **(extra or {})}
    return results


def robust_table(results: dict) -> list[str]:
    labels = list(next(iter(results.values())))
    lines = [
        "| suite | " + " | ".join(f"{label}: success, hover error" for label in labels) + " |",
        "|---|" + "---|" * len(labels),
    ]
    for name, row in results.items():
        cells = []
        for label in labels:
            s = row[label]
            e = s["hover_error_m"]
            err = "n/a" if e is None else ("< 0.1 cm" if e < 0.0005 else f"{100 * e:.1f} cm")
            crashes = f" ({s['crashes']} crash{'es' if s['crashes'] > 1 else ''})" if s["crashes"] else ""
            cells.append(f"{s['success_rate']:.2f}{crashes}, {err}")
        lines.append(f"| {name} | " + " | ".join(cells) + " |")
    return lines


def robust_figure(results: dict, path) -> None:
    from bfc.evaluation.plots import subplots

    names = list(results)
    labels = list(results[names[0]])
    fig, (ax_s, ax_e) = subplots(1, 2, figsize=(13, 4.2))
    width = 0.8 / len(labels)
    for k, label in enumerate(labels):
        xs = [i + k * width for i in range(len(names))]
        ax_s.bar(xs, [results[n][label]["success_rate"] for n in names], width, label=label)
        errs = [results[n][label]["hover_error_m"] for n in names]
        ax_e.bar(xs, [100 * e if e is not None else float("nan") for e in errs], width, label=label)
    for ax, title in ((ax_s, "success rate"), (ax_e, "hover error, median of successful flights (cm)")):
        ax.set_xticks([i + 0.4 - width / 2 for i in range(len(names))], names, rotation=35, ha="right", fontsize=8)
        ax.set_title(title)
    if any(e is not None and e > 0 for row in results.values() for s in row.values() for e in [s["hover_error_m"]]):
        ax_e.set_yscale("log")  # (no successful flight anywhere: nothing to draw on a log scale)
    # One legend above both panels: inside either it hid the first rows' bars
    fig.legend(*ax_s.get_legend_handles_labels(), loc="upper center", ncol=len(labels), fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0, 1, 0.94))
    fig.savefig(path, dpi=110)
