"""Latency: odometry that arrives late, and motor commands that apply late.

A flight computer's state estimate is tens of milliseconds old when the controller reads it
(motion capture, radio, an onboard estimator), and a command reaches the motors a control step or
more after it was computed. Both are whole control steps here (the env only produces odometry
and takes commands at its control rate), and both keep their queue as buffers, so a checkpoint
holds it and a resumed run goes on bit-identically.

- `ObservationDelay`: `"odometry"` is the odometry of `steps` control steps ago (what the sensors
  reported then, noise included when it comes after the noise transform). In the first steps
  after a reset there is no older odometry: the controller sees the reset's, the oldest there is.
- `ActionDelay`: the env applies the command of `steps` control steps ago (rad/s); in the first
  steps after a reset the motors get `initial` (the hover speed: the command a flight computer
  holds before it releases the drone). The policy's own record of its previous command
  (`PolicyObservation`) is what it commanded, not what the motors got.

`steps` is a number, or a (low, high) range from which each env draws its delay at every reset
(uniform over the integers, both ends included): domain randomisation for training.
`range_scale` (1: off) shrinks both ends towards 0 (each rounded to the nearest step): the
curriculum (`latency.curriculum`) grows the delays in as the policy learns to fly, since delays
from the first frame can keep a run from ever learning (bfc/collectors/curriculum.py).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from bfc import keys
from bfc.transforms._base import BatchedTransform, StepState, check, reset_mask


def _delay_range(steps, name: str) -> tuple[int, int]:
    pair = tuple(steps) if isinstance(steps, (list, tuple)) else (steps, steps)
    whole = len(pair) == 2 and all(isinstance(v, int) and not isinstance(v, bool) for v in pair)
    check(
        whole and 0 <= pair[0] <= pair[1],
        name,
        "a whole number of control steps >= 0, or a [low, high] range of them",
        steps,
    )
    return pair


class _Delay(BatchedTransform):
    """A per-env queue of the last `high + 1` values and each env's delay (buffers)."""

    def __init__(self, num_envs: int, steps, width: int, name: str, **keys_kw):
        super().__init__(num_envs, **keys_kw)
        self.low, self.high = _delay_range(steps, name)
        self.register_buffer("queue", torch.zeros(num_envs, self.high + 1, width))  # newest first
        self.register_buffer("delay", torch.full((num_envs,), self.low, dtype=torch.long))
        self._rows = torch.arange(num_envs)
        self.range_scale = 1.0  # set per batch by the curriculum from the frame count (not state)

    def bounds(self) -> tuple[int, int]:
        """The delays drawn at a reset now: (low, high) scaled by `range_scale`, rounded."""
        s = min(max(float(self.range_scale), 0.0), 1.0)
        return int(self.low * s + 0.5), int(self.high * s + 0.5)

    def refill(self, mask: torch.Tensor, value: torch.Tensor) -> None:
        """The envs in `mask` forget their past: every queued value is `value` (n, width)."""
        self.queue[mask] = value[mask].unsqueeze(1).to(self.queue.dtype)
        low, high = self.bounds()
        if self.high > self.low:  # a range draws for every reset (the same stream at any scale)
            drawn = low + (self.rand(self.num_envs) * (high - low + 1)).long().clamp(max=high)
            self.delay[mask] = drawn[mask]
        else:
            self.delay[mask] = low

    def push(self, value: torch.Tensor) -> torch.Tensor:
        """Queue this step's `value` (n, width) and return each env's value of `delay` steps ago."""
        self.queue.copy_(torch.cat([value.unsqueeze(1).to(self.queue.dtype), self.queue[:, :-1]], 1))
        return self.read(value.dtype)

    def read(self, dtype) -> torch.Tensor:
        """Each env's queued value of `delay` steps ago."""
        return self.queue[self._rows, self.delay].to(dtype)


class ObservationDelay(_Delay):
    """`"odometry"` as it was `steps` control steps ago (the reset's in the first steps)."""

    def __init__(self, num_envs: int, steps):
        super().__init__(num_envs, steps, 18, "latency.observation_steps", in_keys=[keys.ODOMETRY])

    def advance(self, state: StepState) -> None:
        state.odometry = self.push(state.odometry)

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        """The envs in `mask` queue their first odometry; every env sees what its queue says now."""
        self.refill(mask, state.odometry)
        state.odometry = self.read(state.odometry.dtype)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        state = StepState(odometry=next_tensordict.get(keys.ODOMETRY))
        self.advance(state)
        return next_tensordict.set(keys.ODOMETRY, state.odometry)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        state = StepState(odometry=tensordict_reset.get(keys.ODOMETRY))
        self.restart(state, reset_mask(tensordict, self.num_envs))
        return tensordict_reset.set(keys.ODOMETRY, state.odometry)


class ActionDelay(_Delay):
    """The env applies the command (rad/s) of `steps` control steps ago; `initial` before that."""

    before_physics = True

    def __init__(self, num_envs: int, steps, initial: float):
        super().__init__(num_envs, steps, 4, "latency.action_steps")
        self.in_keys_inv, self.out_keys_inv = [keys.ACTION], [keys.ACTION]
        check(initial >= 0, "initial", ">= 0 (rad/s)", initial)
        self.initial = float(initial)

    def advance(self, state: StepState) -> None:
        state.applied = self.push(state.command)

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        """The envs in `mask` start again: their motors get `initial` until their first command arrives."""
        self.refill(mask, torch.full((self.num_envs, 4), self.initial))

    def _inv_call(self, tensordict: TensorDictBase) -> TensorDictBase:
        state = StepState(command=tensordict.get(keys.ACTION))
        self.advance(state)
        return tensordict.set(keys.ACTION, state.applied)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        # The transforms after this one see the inverse-transformed input: give them back the
        # command as commanded (the newest in the queue), so the policy's record of its previous
        # command is its own, as on a flight computer that feeds its output back.
        tensordict.set(keys.ACTION, self.queue[:, 0].clone())
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        self.restart(StepState(), reset_mask(tensordict, self.num_envs))
        return tensordict_reset
