"""Odometry noise: Gaussian and Ornstein-Uhlenbeck, on chosen elements of `"odometry"` only.

Ground truth under `"state"` is never touched. Noise is applied on reset as well as on step.
`bias` adds a constant offset per episode (N(0, bias^2) per element, drawn at each reset): a
gyro's bias, an estimator's drift. With bias 0 nothing is drawn for it (earlier runs reproduce).
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

from bfc import keys
from bfc.transforms._base import BatchedTransform, StepState, check, reset_mask

ODOMETRY_SIZE = 18
ELEMENT_SETS = {"all": list(range(18)), "position": [0, 1, 2]}


def element_mask(elements) -> torch.Tensor:
    """(18,) bool mask from `all`, `position` or an explicit list of odometry indices."""
    if isinstance(elements, str):
        check(
            elements in ELEMENT_SETS, "noise.elements", f"one of {sorted(ELEMENT_SETS)} or a list of indices", elements
        )
        idx = ELEMENT_SETS[elements]
    else:
        idx = list(elements)
        check(
            len(idx) > 0 and all(isinstance(i, int) and 0 <= i < ODOMETRY_SIZE for i in idx),
            "noise.elements",
            "'all', 'position' or a non-empty list of integers in [0, 17]",
            elements,
        )
    mask = torch.zeros(ODOMETRY_SIZE, dtype=torch.bool)
    mask[idx] = True
    return mask


def _std_vector(std, name: str = "noise.std") -> torch.Tensor:
    std_t = torch.as_tensor(std, dtype=torch.float32)
    check(
        std_t.ndim == 0 or std_t.shape == (ODOMETRY_SIZE,),
        name,
        "a number or a list of 18 numbers (one per odometry element)",
        std,
    )
    check(bool(torch.isfinite(std_t).all() and (std_t >= 0).all()), name, "finite and >= 0", std)
    return std_t.expand(ODOMETRY_SIZE).clone()


class OdometryNoise(BatchedTransform):
    """What the noise models share: a per-element std (zero outside `elements`) and `corrupt`."""

    def __init__(self, num_envs: int, std, elements="all", bias=0.0):
        super().__init__(num_envs, in_keys=[keys.ODOMETRY], out_keys=[keys.ODOMETRY])
        self.register_buffer("std", _std_vector(std) * element_mask(elements))
        bias = _std_vector(bias, "noise.bias")
        self.biased = bool((bias > 0).any())
        if self.biased:  # buffers only when used: an unbiased run's checkpoint keeps its keys
            self.register_buffer("bias_std", bias)
            self.register_buffer("offset", torch.zeros(num_envs, ODOMETRY_SIZE))

    def noise(self, mask: torch.Tensor | None) -> torch.Tensor:
        """(N, 18) the noise of this step (mask None) or of a reset of the envs in `mask`."""
        raise NotImplementedError

    def corrupt(self, odometry: torch.Tensor, mask: torch.Tensor | None = None) -> torch.Tensor:
        """What the sensors report: `odometry` (N, 18) plus this step's noise (or a reset's, for
        the envs in `mask`); a new tensor."""
        noisy = odometry + self.noise(mask)
        if not self.biased:
            return noisy
        if mask is not None:  # a reset: these envs draw their offset for the episode
            drawn = self.randn(self.num_envs, ODOMETRY_SIZE) * self.bias_std
            self.offset.copy_(torch.where(mask.unsqueeze(-1), drawn, self.offset))
        return noisy + self.offset

    def advance(self, state: StepState) -> None:
        state.odometry = self.corrupt(state.odometry)

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        state.odometry = self.corrupt(state.odometry, mask)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        state = StepState(odometry=next_tensordict.get(keys.ODOMETRY))
        self.advance(state)
        return next_tensordict.set(keys.ODOMETRY, state.odometry)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        state = StepState(odometry=tensordict_reset.get(keys.ODOMETRY))
        self.restart(state, reset_mask(tensordict, self.num_envs))
        return tensordict_reset.set(keys.ODOMETRY, state.odometry)


class GaussianOdometryNoise(OdometryNoise):
    """Adds N(0, std^2) independently per element and step (std a number or 18 numbers)."""

    def noise(self, mask):
        return self.randn(self.num_envs, ODOMETRY_SIZE) * self.std


class OUOdometryNoise(OdometryNoise):
    """Ornstein-Uhlenbeck noise, dx = -theta x dt + sigma dW, discretised exactly at the env step.

    `std` is the stationary standard deviation (sigma = std sqrt(2 theta)), so Gaussian and OU
    noise at the same std compare. Each env's process restarts from 0 at its reset.
    """

    def __init__(self, num_envs: int, std, theta: float = 1.0, dt: float = 0.004, elements="all", bias=0.0):
        check(math.isfinite(theta) and theta > 0, "noise.theta", "> 0", theta)
        check(dt > 0, "noise.dt", "> 0", dt)
        super().__init__(num_envs, std, elements, bias)
        self.theta, self.dt = float(theta), float(dt)
        self.decay = math.exp(-theta * dt)
        self.innovation = math.sqrt(1 - self.decay**2)  # keeps the stationary std at `std`
        self.register_buffer("x", torch.zeros(num_envs, ODOMETRY_SIZE))

    def noise(self, mask):
        if mask is not None:  # reset: restart the process of these envs
            self.x[mask] = 0.0
        else:
            self.x.mul_(self.decay).add_(self.randn(self.num_envs, ODOMETRY_SIZE) * self.std * self.innovation)
        return self.x.clone()
