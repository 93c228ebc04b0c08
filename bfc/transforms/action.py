"""The policy acts in [-1, 1]^4, centred on hover (a = 0 commands the hover speed); the env always
receives rad/s, clipped to [0, max].

Two maps, with the same slope at hover (so learning starts alike):
- "thrust" (default): thrust = hover thrust (1 + 2a), speed = hover sqrt(1 + 2a). Thrust and the
  body torques are linear in the action, so the policy's Gaussian exploration noise averages out:
  the deterministic (mean) policy flies the thrust the noisy one learned to fly.
- "speed": speed = hover (1 + a). Thrust grows with speed squared, so noise adds mean thrust
  (E[(1 + a)^2] = (1 + mean)^2 + std^2) and per-motor noise adds a yaw torque: the mean policy
  then sits low and spins (measured: 8 cm low, yaw rate 8 rad/s after 10 s; docs/training.md).
"""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Composite
from torchrl.envs import Transform

from bfc import keys
from bfc.transforms._base import Stage, StepState, check

ACTION_MAPS = ("thrust", "speed")


class MotorSpeedAction(Transform, Stage):
    before_physics = True

    def __init__(self, hover_speed: float, max_speed: float, action_map: str = "thrust"):
        super().__init__(in_keys_inv=[keys.ACTION], out_keys_inv=[keys.ACTION])
        check(0 < hover_speed < max_speed, "hover_speed", f"in (0, max_speed={max_speed})", hover_speed)
        check(action_map in ACTION_MAPS, "model.action_map", " or ".join(ACTION_MAPS), action_map)
        self.hover_speed, self.max_speed, self.action_map = float(hover_speed), float(max_speed), action_map

    def advance(self, state: StepState) -> None:
        state.command = self.to_command(state.action)

    def _inv_apply_transform(self, action: torch.Tensor) -> torch.Tensor:
        return self.to_command(action)

    def to_command(self, action: torch.Tensor) -> torch.Tensor:
        """The policy's action -> motor speed commands (rad/s)."""
        if self.action_map == "thrust":
            return self.hover_speed * (1.0 + 2.0 * action).clamp(0.0, (self.max_speed / self.hover_speed) ** 2).sqrt()
        return (self.hover_speed * (1.0 + action)).clamp(0.0, self.max_speed)

    def _apply_transform(self, command: torch.Tensor) -> torch.Tensor:
        return self.to_action(command)

    def to_action(self, command: torch.Tensor) -> torch.Tensor:
        """Motor speeds (rad/s) -> the policy's action that commands them."""
        if self.action_map == "thrust":
            return ((command / self.hover_speed) ** 2 - 1.0) / 2.0
        return command / self.hover_speed - 1.0

    def transform_action_spec(self, action_spec):
        def normalised(spec):
            return Bounded(low=-1.0, high=1.0, shape=spec.shape, dtype=spec.dtype, device=spec.device)

        if isinstance(action_spec, Composite):  # the full action spec
            action_spec[keys.ACTION] = normalised(action_spec[keys.ACTION])
            return action_spec
        return normalised(action_spec)
