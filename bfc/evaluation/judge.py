"""The one success rule, used by training's evaluator, `fly`'s helpers, the metrics and the reports.

A flight succeeds when the drone stays inside goal +/- threshold on every axis for hold_seconds
of consecutive steps, at any time of the flight, before any crash. The time to success is when it
entered the box for the hold that succeeded.
"""

from __future__ import annotations

from typing import NamedTuple

import torch
from tensordict import TensorDict

from bfc import keys


class Verdict(NamedTuple):
    success: torch.Tensor  # (n,) bool
    time: torch.Tensor  # (n,) seconds to success, NaN where not successful
    inside: torch.Tensor  # (n, T) bool: inside the box and not crashed, per step


def inside_box(position: torch.Tensor, goal, threshold: float) -> torch.Tensor:
    """(..., T) bool: every axis within goal +/- threshold. position (..., T, 3); goal (3,) or (..., T, 3)."""
    goal = torch.as_tensor(goal, dtype=position.dtype)
    return ((position - goal).abs() <= threshold).all(-1)


def longest_run_end(inside: torch.Tensor) -> torch.Tensor:
    """(n, T) int: length of the run of consecutive True ending at each step."""
    t = torch.arange(inside.shape[-1]).expand_as(inside)
    last_out = torch.where(~inside, t, torch.full_like(t, -1)).cummax(-1).values
    return t - last_out


def success_and_time(inside: torch.Tensor, hold_steps: int, dt: float) -> tuple[torch.Tensor, torch.Tensor]:
    """(success (n,), time-to-success in seconds (n,), NaN when not successful) from per-step
    `inside` (n, T) flags."""
    run = longest_run_end(inside)
    reached = run >= hold_steps
    ok = reached.any(-1)
    first = torch.where(ok, reached.float().argmax(-1), torch.zeros_like(ok, dtype=torch.long))
    entered = first - hold_steps + 1
    t = torch.where(ok, (entered + 1).float() * dt, torch.full(ok.shape, float("nan")))
    return ok, t


def flight_dt(trajectory: TensorDict) -> float:
    """The control period of a trajectory from its `"time"` column."""
    time = trajectory.get("time")
    return float(time[0, 1] - time[0, 0]) if time.shape[1] > 1 else float(time[0, 0])


def judge(trajectory: TensorDict, threshold: float = 0.10, hold_seconds: float = 1.0, goal=None) -> Verdict:
    """The verdict on a batch of flights (a `run_flights` / `fly` trajectory of shape (n, T)).

    goal None: the trajectory's own (possibly scheduled) goal at each step.
    """
    if threshold <= 0:
        raise ValueError(f"threshold must be > 0 (metres), got {threshold}")
    if hold_seconds <= 0:
        raise ValueError(f"hold_seconds must be > 0, got {hold_seconds}")
    dt = flight_dt(trajectory)
    pos = trajectory.get(keys.POSITION)
    goal = trajectory.get(keys.GOAL) if goal is None else torch.as_tensor(goal, dtype=pos.dtype)
    alive = trajectory.get("alive", torch.ones(pos.shape[:2], dtype=torch.bool))
    inside = inside_box(pos, goal, threshold) & alive
    ok, t = success_and_time(inside, max(1, round(hold_seconds / dt)), dt)
    return Verdict(ok, t, inside)


def success(trajectory: TensorDict, goal=None, threshold: float = 0.10, hold_seconds: float = 1.0) -> torch.Tensor:
    """(n,) bool: the success of each flight (see the module docstring)."""
    return judge(trajectory, threshold, hold_seconds, goal).success


def time_to_success(trajectory: TensorDict, goal=None, threshold: float = 0.10, hold_seconds: float = 1.0):
    """(n,) seconds from the start until the drone entered the box for the hold that succeeded (NaN: never)."""
    return judge(trajectory, threshold, hold_seconds, goal).time
