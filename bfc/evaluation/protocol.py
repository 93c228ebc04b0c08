"""The paper's evaluation protocol: fixed random starts in the air, fly 10 s, success rule.

protocol_starts(n, seed) gives the same starts on every machine (a CPU torch.Generator):
x, y uniform in [-2, 2] m, z uniform in [0.5, 3] m, roll and pitch uniform in [-60, 60] deg,
yaw uniform in [-180, 180] deg, at rest. Success: inside goal +/- threshold on every axis for
hold_seconds of consecutive steps, at any time of the flight, and never crashed before that.
"""

from __future__ import annotations

import math

import torch


def protocol_starts(n: int = 100, seed: int = 0) -> torch.Tensor:
    """(n, 12) starts in the `"start_state"` layout (see module docstring)."""
    if n < 1:
        raise ValueError(f"n must be >= 1, got {n}")
    g = torch.Generator().manual_seed(int(seed))
    u = torch.rand(n, 6, generator=g, dtype=torch.float64)
    deg = math.pi / 180
    start = torch.zeros(n, 12, dtype=torch.float64)
    start[:, 0:2] = -2 + 4 * u[:, 0:2]
    start[:, 2] = 0.5 + 2.5 * u[:, 2]
    start[:, 3:5] = (-60 + 120 * u[:, 3:5]) * deg
    start[:, 5] = (-180 + 360 * u[:, 5]) * deg
    return start.float()


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
    """(success (n,), time-to-success in seconds (n,), NaN when not successful).

    The time is when the drone entered the box for the hold that succeeded.
    """
    run = longest_run_end(inside)
    reached = run >= hold_steps
    ok = reached.any(-1)
    first = torch.where(ok, reached.float().argmax(-1), torch.zeros_like(ok, dtype=torch.long))
    entered = first - hold_steps + 1
    t = torch.where(ok, (entered + 1).float() * dt, torch.full(ok.shape, float("nan")))
    return ok, t
