"""What the flight-side controllers of an exported policy share (`OnnxController`, `CController`).

An exported policy is a pure function of odometry, goal, the previous command, (for integral
policies) the integral and (for `command_history` policies) the commands before the previous one;
the caller keeps that state and feeds it back, as flight firmware does.
`FedBackController` keeps it per drone and restarts it where a flight restarts, so both exports
fly through `fly` exactly as the policy file does.
"""

from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from bfc import keys


def restart_mask(td: TensorDictBase) -> np.ndarray | None:
    """Which envs restart their flight at this call (TorchRL's `"is_init"`, or `"step_count" == 0`);
    None when the input says neither. Every controller that keeps per-drone state reads it here."""
    if "is_init" in td.keys():
        return td.get("is_init").reshape(-1).cpu().numpy().astype(bool)
    if "step_count" in td.keys():
        return (td.get("step_count").reshape(-1) == 0).cpu().numpy()
    return None


class FedBackController(TensorDictModuleBase):
    """Reads `"odometry"` and `"goal"`, writes `"action"` (rad/s), and feeds its own last command
    (integral, history) back. The previous command and the history start at the hover speed (the
    integral at zero) for every env: at the first call, at a call whose batch size differs from the stored state,
    after `reset()` (also `begin_flight()`, which flight runners call before a flight), and per env
    where the input carries TorchRL's `"is_init"` (InitTracker) or `"step_count" == 0`.
    Subclasses set `hover_speed` (and `command_history` when they have one) and implement `step`."""

    hover_speed: float
    command_history: int = 0

    def __init__(self):
        super().__init__()
        self.in_keys = [keys.ODOMETRY, keys.GOAL]
        self.out_keys = [keys.ACTION]
        self.previous_motor_speeds: np.ndarray | None = None
        self.integral: np.ndarray | None = None
        self.history: np.ndarray | None = None

    def step(self, odometry: np.ndarray, goal: np.ndarray, previous: np.ndarray, integral: np.ndarray, history):
        """One control step for n drones (`history` (n, k, 4) rad/s, newest first): (motor speeds
        (n, 4), the next integral (n, 3) or None)."""
        raise NotImplementedError

    def reset(self) -> None:
        """Forget the previous command: the next call starts every env from hover."""
        self.previous_motor_speeds = None
        self.integral = None
        self.history = None

    def begin_flight(self) -> None:
        self.reset()

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        odometry = td.get(keys.ODOMETRY)
        goal = td.get(keys.GOAL)
        n = odometry.shape[0]
        goal = goal.expand(n, 3) if goal.ndim == 1 else goal
        previous, integral, history = self.previous_motor_speeds, self.integral, self.history
        if previous is None or previous.shape[0] != n:
            previous = np.full((n, 4), self.hover_speed, dtype=np.float32)
            integral = np.zeros((n, 3), dtype=np.float32)
            history = np.full((n, self.command_history, 4), self.hover_speed, dtype=np.float32)
        mask = restart_mask(td)
        if mask is not None and mask.any():
            previous, integral, history = previous.copy(), integral.copy(), history.copy()
            previous[mask] = self.hover_speed
            integral[mask] = 0.0
            history[mask] = self.hover_speed
        speeds, next_integral = self.step(
            odometry.detach().cpu().numpy().astype(np.float32, copy=False),
            goal.detach().cpu().numpy().astype(np.float32, copy=False),
            previous,
            integral,
            history,
        )
        # the history one step on (PolicyObservation.shift): the previous command is its newest
        self.history = np.concatenate([previous[:, None], history[:, :-1]], 1)
        self.previous_motor_speeds = speeds
        self.integral = next_integral if next_integral is not None else integral
        td.set(keys.ACTION, torch.from_numpy(speeds.copy()).to(odometry.device))
        return td
