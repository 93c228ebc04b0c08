"""GivenStarts: place envs at chosen starts on their next reset (evaluation, tests).

`transform.starts` is (n, 12) in the `"start_state"` layout; NaN entries are left to the other
samplers or to the task distribution D.
"""

from __future__ import annotations

import torch

from bfc.transforms._base import StartSampler


class GivenStarts(StartSampler):
    def __init__(self, num_envs: int):
        super().__init__(num_envs)
        self.register_buffer("starts", torch.full((num_envs, 12), float("nan")))

    def set_starts(self, starts: torch.Tensor) -> None:
        if starts.shape != (self.num_envs, 12):
            raise ValueError(f"starts must have shape ({self.num_envs}, 12), got {tuple(starts.shape)}")
        self.starts.copy_(starts)

    def fill_starts(self, start: torch.Tensor, mask: torch.Tensor) -> None:
        given = ~torch.isnan(self.starts) & mask.unsqueeze(-1)
        start.copy_(torch.where(given, self.starts, start))
