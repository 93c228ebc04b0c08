"""What every bfc transform shares: the reset mask, a seedable generator, argument checks."""

from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import Transform

from bfc import keys
from bfc.checks import check
from bfc.transforms.pipeline import Stage, StepState

__all__ = ["BatchedTransform", "StartSampler", "Stage", "StepState", "check", "reset_mask"]


def reset_mask(tensordict: TensorDictBase | None, n: int) -> torch.Tensor:
    """(n,) bool: the envs this reset concerns (all of them without a `"_reset"` entry)."""
    if tensordict is None or keys.RESET not in tensordict.keys():
        return torch.ones(n, dtype=torch.bool)
    return tensordict.get(keys.RESET).reshape(n)


class BatchedTransform(Transform, Stage):
    """A transform over an env with batch_size (num_envs,), holding per-env state as buffers, and a
    stage of the pipeline (bfc.transforms.pipeline): its TorchRL hooks call its `advance` / `restart`.

    Buffers go into `state_dict`, so whatever must survive checkpoint/resume is a buffer.
    Random draws come from the transform's own generator, seeded by `set_seed` (make_env seeds
    every transform from the run's seed, next to the env).
    """

    def __init__(self, num_envs: int, in_keys=None, out_keys=None):
        super().__init__(in_keys=in_keys or [], out_keys=out_keys or [])
        check(isinstance(num_envs, int) and num_envs >= 1, "num_envs", "an integer >= 1", num_envs)
        self.num_envs = num_envs
        self.generator = torch.Generator()
        self.generator.manual_seed(0)

    def set_seed(self, seed: int) -> None:
        self.generator.manual_seed(int(seed))

    def get_extra_state(self) -> dict:
        """The generator's state goes into `state_dict()` beside the buffers."""
        return {"generator": self.generator.get_state()}

    def set_extra_state(self, state: dict) -> None:
        self.generator.set_state(state["generator"])

    def rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.generator)

    def randn(self, *shape: int) -> torch.Tensor:
        return torch.randn(*shape, generator=self.generator)


class StartSampler(BatchedTransform):
    """A transform that fills part of `"start_state"` before the env resets.

    A sampler fills only the entries that are still NaN: a `"start_state"` given to `reset()` (or
    written by a sampler that ran before) wins, so `env.reset(TensorDict(start_state=...))`
    places envs exactly as on the base env. Entries left NaN are drawn by the env from the task
    distribution D, so samplers compose without knowing about each other (CSS writes x, y; JD
    height, attitude and velocities). Its random draws are the same whatever was given.
    """

    def _reset_env_preprocess(self, tensordict: TensorDictBase | None) -> TensorDictBase:
        n = self.num_envs
        if tensordict is None:
            tensordict = TensorDict({}, batch_size=[n])
        start = self.draw_starts(reset_mask(tensordict, n), tensordict.get(keys.START_STATE, None))
        tensordict.set(keys.START_STATE, start)
        return tensordict

    def draw_starts(self, mask: torch.Tensor, given: torch.Tensor | None = None) -> torch.Tensor:
        """(n, 12) starts for the envs in `mask`: `given`'s entries where they are not NaN, this
        sampler's draws where they are (NaN where neither: the env draws those from D)."""
        n = self.num_envs
        start = torch.full((n, 12), float("nan"))
        self.fill_starts(start, mask)
        if given is None:
            return start
        if given.shape != (n, 12):
            raise ValueError(f"start_state must have shape ({n}, 12), got {tuple(given.shape)}")
        return torch.where(torch.isnan(given), start, given.to(start.dtype))

    def fill_starts(self, start: torch.Tensor, mask: torch.Tensor) -> None:
        """Write this sampler's entries of `start` (n, 12) for the envs in `mask`, in place."""
        raise NotImplementedError
