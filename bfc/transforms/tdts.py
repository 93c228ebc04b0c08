"""Time-Dependent Terminal State (TDTS, paper sec. 4.3, eq. 19).

When an env has stayed within zeta of the goal on every axis (true state) for threshold_seconds,
its episode ends, so that the batch does not fill up with easy hovering samples, and the env is
re-placed through the same samplers. `as_terminal=False` (default) reports it as `truncated`: the
value still bootstraps, because staying at the goal is good and ending there must not look like
a loss (as `terminated`, with positive per-step rewards, the critic sees 0 future reward at the
goal and the policy learns to hover just outside the zeta box).
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

from bfc import keys
from bfc.transforms._base import BatchedTransform, check, reset_mask


class TimeDependentTerminalState(BatchedTransform):
    def __init__(
        self, num_envs: int, zeta: float = 0.1, threshold_seconds: float = 1.0, dt: float = 0.004, as_terminal=False
    ):
        super().__init__(num_envs)
        check(math.isfinite(zeta) and zeta > 0, "tdts.zeta", "> 0 (metres)", zeta)
        check(
            math.isfinite(threshold_seconds) and threshold_seconds > 0,
            "tdts.threshold_seconds",
            "> 0",
            threshold_seconds,
        )
        check(dt > 0, "tdts.dt", "> 0", dt)
        self.zeta, self.threshold_seconds, self.as_terminal = float(zeta), float(threshold_seconds), bool(as_terminal)
        self.threshold_steps = max(1, round(threshold_seconds / dt))
        self.register_buffer("inside_steps", torch.zeros(num_envs, dtype=torch.long))
        self.register_buffer("fired", torch.zeros((), dtype=torch.long))  # TDT events so far (train/tdts_fired)

    def advance(self, position: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """One control step of the timers from the true position and the goal (N, 3) each:
        (N,) bool, the envs whose time-dependent terminal state fires now."""
        inside = ((position - goal).abs() <= self.zeta).all(-1)
        self.inside_steps.copy_(torch.where(inside, self.inside_steps + 1, 0))
        fire = self.inside_steps >= self.threshold_steps
        self.fired += fire.sum()
        return fire

    def restart(self, mask: torch.Tensor) -> None:
        """The timers of the envs in `mask` (N,) start again (their episode restarts)."""
        self.inside_steps.masked_fill_(mask, 0)

    @property
    def flag(self) -> str:
        """The done entry a firing sets beside `"done"`: terminated or truncated (`as_terminal`)."""
        return keys.TERMINATED if self.as_terminal else keys.TRUNCATED

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        fire = self.advance(next_tensordict.get(keys.POSITION), next_tensordict.get(keys.GOAL))
        if bool(fire.any()):
            flag = fire.unsqueeze(-1)
            next_tensordict.set(self.flag, next_tensordict.get(self.flag) | flag)
            next_tensordict.set(keys.DONE, next_tensordict.get(keys.DONE) | flag)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        self.restart(reset_mask(tensordict, self.num_envs))
        return tensordict_reset
