"""The policy acts in [-1, 1]^4, centred on hover: motor speed = hover (1 + a), clipped to [0, max].

Zero means hover, so an untrained policy with a small std starts near a hover (a known help for
learning motor-speed control); the env itself always receives rad/s.
"""

from __future__ import annotations

import torch
from torchrl.data import Bounded, Composite
from torchrl.envs import Transform

from bfc import keys
from bfc.transforms._base import check


class MotorSpeedAction(Transform):
    def __init__(self, hover_speed: float, max_speed: float):
        super().__init__(in_keys_inv=[keys.ACTION], out_keys_inv=[keys.ACTION])
        check(0 < hover_speed < max_speed, "hover_speed", f"in (0, max_speed={max_speed})", hover_speed)
        self.hover_speed, self.max_speed = float(hover_speed), float(max_speed)

    def _inv_apply_transform(self, action: torch.Tensor) -> torch.Tensor:
        return (self.hover_speed * (1.0 + action)).clamp(0.0, self.max_speed)

    def _apply_transform(self, command: torch.Tensor) -> torch.Tensor:
        return command / self.hover_speed - 1.0

    def transform_action_spec(self, action_spec):
        def normalised(spec):
            return Bounded(low=-1.0, high=1.0, shape=spec.shape, dtype=spec.dtype, device=spec.device)

        if isinstance(action_spec, Composite):  # the full action spec
            action_spec[keys.ACTION] = normalised(action_spec[keys.ACTION])
            return action_spec
        return normalised(action_spec)
