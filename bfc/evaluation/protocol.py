"""The paper's evaluation protocol: fixed random starts in the air, flown 10 s, judged by
`bfc.evaluation.judge`.

protocol_starts(n, seed) gives the same starts on every machine (a CPU torch.Generator):
x, y uniform in [-2, 2] m, z uniform in [0.5, 3] m, roll and pitch each uniform in [-60, 60] deg,
yaw uniform in [-180, 180] deg, at rest.

Seeds: the starts that reports quote (the test set) are seed 0 (`TEST_SEED`); training chooses
`policy.pt` on another draw (`eval.seed`, default `VALIDATION_SEED`), so no reported number comes
from the starts a policy was picked on.
"""

from __future__ import annotations

import math

import torch

TEST_SEED = 0
VALIDATION_SEED = 1


def protocol_starts(n: int = 100, seed: int = TEST_SEED) -> torch.Tensor:
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
