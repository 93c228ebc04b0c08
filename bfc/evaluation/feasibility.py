"""Is a crash the controller's or the body's? A search for motor commands that avoid it.

A row a policy misses (motor lag x3 on the Crazyflie, say) may ask for what no controller can do:
released at rest with slow motors, low and tilted, a body may reach the floor too fast whatever
it commands. `search_start` answers per start with the cross-entropy method on the real
simulator: it flies a population of open-loop plans (the four motor speeds, held for
`knot_seconds` each) from that one start through the row's body, and keeps the best. A plan that
ends its horizon uncrashed, upright and slow proves the crash can be avoided (the controller has the
rest of the flight to reach the goal; resting level on the floor is no crash, and a ground start
takes off). A search that finds none proves nothing: it reports how hard it looked.

The plans know the start and the body exactly and act without latency: more than any controller
is given, so a start they cannot save is the hardest kind of start, and one they save is a miss
of the controller's.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

import torch
from tensordict.nn import TensorDictModule

from bfc import keys
from bfc.envs.params import AirframeParams
from bfc.evaluation.flying import fly


@dataclass(frozen=True)
class SearchBudget:
    """How hard `search_start` looks: population x iterations rollouts of horizon_seconds."""

    population: int = 1000
    iterations: int = 40
    elite: int = 50
    knot_seconds: float = 0.04  # each plan holds its four speeds this long
    horizon_seconds: float = 2.0
    upright_cos: float = 0.9  # the end of a saving plan: tilted less than ~26 deg ...
    slow_speed: float = 1.0  # ... and slower than this (m/s)

    def __post_init__(self) -> None:
        if not (1 <= self.elite <= self.population and self.iterations >= 1):
            raise ValueError(f"need 1 <= elite <= population and iterations >= 1, got {self}")
        if not (0 < self.knot_seconds <= self.horizon_seconds):
            raise ValueError(f"need 0 < knot_seconds <= horizon_seconds, got {self}")


@dataclass
class Feasibility:
    """One start's answer: `saved` (a plan was found), after `rollouts` flights, and the plan
    ((knots, 4) motor speeds, rad/s) that saved it or came closest."""

    saved: bool
    rollouts: int
    plan: torch.Tensor
    first_crash_s: float | None  # the closest plan's crash time (None: it did not crash)


class _OpenLoop(torch.nn.Module):
    """Flies plans (n, knots, 4) rad/s: knot k for control steps [k * steps_per_knot, ...)."""

    def __init__(self, plans: torch.Tensor, steps_per_knot: int) -> None:
        super().__init__()
        self.plans, self.steps_per_knot, self.step = plans, steps_per_knot, 0

    def forward(self, odometry: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        knot = min(self.step // self.steps_per_knot, self.plans.shape[1] - 1)
        self.step += 1
        return self.plans[:, knot]


def _fly_plans(plans, start, nominal, flown, control_hz, budget, steps_per_knot, start_motors, wind):
    """(cost, saved, crash step or -1) per plan, from one start."""
    n = plans.shape[0]
    wind = None if wind is None else torch.as_tensor(wind, dtype=torch.float64).reshape(1, 3).expand(n, 3).clone()
    controller = TensorDictModule(_OpenLoop(plans, steps_per_knot), [keys.ODOMETRY, keys.GOAL], [keys.ACTION])
    f = fly(
        controller,
        start.expand(n, 12).clone(),
        seconds=budget.horizon_seconds,
        control_hz=control_hz,
        airframe=flown,
        nominal=dataclasses.asdict(nominal),
        start_motors=start_motors,
        external_force=wind,
    )
    alive = f.get("alive")
    steps_alive = alive.sum(1)
    crashed = ~alive[:, -1]
    q = f.get(keys.QUATERNION)[:, -1]
    cos_tilt = 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2)
    speed = f.get(keys.LINEAR_VELOCITY)[:, -1].norm(dim=-1)
    # a crash costs more the earlier it comes; an uncrashed end costs its tilt and speed
    cost = crashed.float() * (1000.0 + 10.0 * (alive.shape[1] - steps_alive)) + 10 * (1 - cos_tilt) + 3 * speed
    saved = ~crashed & (cos_tilt > budget.upright_cos) & (speed < budget.slow_speed)
    return cost, saved, torch.where(crashed, steps_alive, -1)


def search_start(
    start: torch.Tensor,
    nominal: AirframeParams,
    flown: dict | None = None,
    control_hz: float = 50.0,
    budget: SearchBudget = SearchBudget(),
    seed: int = 0,
    start_motors: str = "rest",
    wind: torch.Tensor | None = None,
) -> Feasibility:
    """Search for motor commands that fly `start` (12,) without a crash, on `nominal` changed by
    `flown` (AirframeParams overrides, as a suite row gives them), the motors at `start_motors`
    ("rest" or "hover") at release, pushed by `wind` (3,) N where given."""
    steps_per_knot = max(1, round(budget.knot_seconds * control_hz))
    knots = math.ceil(budget.horizon_seconds * control_hz / steps_per_knot)
    low, high = nominal.min_rotor_speed, nominal.max_rotor_speed
    g = torch.Generator().manual_seed(seed)
    mean = torch.full((knots, 4), 0.9)  # fractions of the range: near full thrust to begin with
    std = torch.full((knots, 4), 0.4)
    best_cost, best_plan, best_crash = float("inf"), None, -1
    start = torch.as_tensor(start, dtype=torch.float32).reshape(1, 12)
    for it in range(budget.iterations):
        u = (mean + std * torch.randn(budget.population, knots, 4, generator=g)).clamp(0, 1)
        u[0] = mean.clamp(0, 1)
        plans = low + u * (high - low)
        cost, saved, crash = _fly_plans(
            plans, start, nominal, flown, control_hz, budget, steps_per_knot, start_motors, wind
        )
        rollouts = (it + 1) * budget.population
        if saved.any():
            i = int(torch.nonzero(saved)[0])
            return Feasibility(True, rollouts, plans[i], None)
        order = cost.argsort()
        if cost[order[0]] < best_cost:
            best_cost, best_plan, best_crash = float(cost[order[0]]), plans[order[0]], int(crash[order[0]])
        elite = u[order[: budget.elite]]
        mean, std = elite.mean(0), elite.std(0).clamp_min(0.05)
    crash_s = None if best_crash < 0 else best_crash / control_hz
    return Feasibility(False, budget.iterations * budget.population, best_plan, crash_s)
