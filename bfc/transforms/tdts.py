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
from bfc.transforms._base import BatchedTransform, StepState, check, reset_mask


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

    def tick(self, position: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """One control step of the timers from the true position and the goal (N, 3) each:
        (N,) bool, the envs whose time-dependent terminal state fires now."""
        inside = ((position - goal).abs() <= self.zeta).all(-1)
        self.inside_steps.copy_(torch.where(inside, self.inside_steps + 1, 0))
        fire = self.inside_steps >= self.threshold_steps
        self.fired += fire.sum()
        return fire

    def advance(self, state: StepState) -> None:
        """A firing ends the episode: `truncated` (or `terminated`, `as_terminal`)."""
        fire = self.tick(state.position, state.goal)
        if self.as_terminal:
            state.terminated = state.terminated | fire
        else:
            state.truncated = state.truncated | fire

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        """The timers of the envs in `mask` (N,) start again (their episode restarts)."""
        self.inside_steps.masked_fill_(mask, 0)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        n, nxt = self.num_envs, next_tensordict
        state = StepState(position=nxt.get(keys.POSITION), goal=nxt.get(keys.GOAL))
        state.terminated, state.truncated = nxt.get(keys.TERMINATED).reshape(n), nxt.get(keys.TRUNCATED).reshape(n)
        self.advance(state)
        nxt.set(keys.TERMINATED, state.terminated.unsqueeze(-1))
        nxt.set(keys.TRUNCATED, state.truncated.unsqueeze(-1))
        return nxt.set(keys.DONE, nxt.get(keys.DONE) | (state.terminated | state.truncated).unsqueeze(-1))

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        self.restart(StepState(), reset_mask(tensordict, self.num_envs))
        return tensordict_reset
