"""Running observation statistics, as OpenAI Baselines' VecNormalize kept them (for `+preset=paper`).

`ObservationNorm` is part of the policy network (its mean, variance and count are buffers in the
actor's state_dict, so a policy file carries them and an export bakes them in): it maps an
observation to clip((x - mean) / sqrt(var + eps), -clip, clip). The critic shares the same module.
Training updates the statistics once per batch, after the update (`update`), so a batch collected
in the learner's process is scored with the statistics it was collected with (PPO's ratio starts
at 1; with collector workers they lag one update, as the weights do). Baselines updated them at
every env step (docs/training.md, "The paper preset").

`RunningMeanStd` is the parallel-variance recursion (Chan et al.) both use; `RewardScale` is
VecNormalize's reward half: rewards divided by the running std of each env's discounted return.
"""

from __future__ import annotations

import torch
from torch import nn


def merge_moments(mean, var, count, batch_mean, batch_var, batch_count):
    """(mean, var, count) of two samples' union from each one's mean, variance and count."""
    delta = batch_mean - mean
    total = count + batch_count
    new_mean = mean + delta * batch_count / total
    m2 = var * count + batch_var * batch_count + delta.square() * count * batch_count / total
    return new_mean, m2 / total, total


class ObservationNorm(nn.Module):
    """clip((x - mean) / sqrt(var + eps), -clip, clip), with the statistics as buffers (float64
    count, as Baselines' RunningMeanStd starting from count 1e-4, mean 0, var 1)."""

    def __init__(self, size: int, clip: float = 10.0, eps: float = 1e-8):
        super().__init__()
        self.clip, self.eps = float(clip), float(eps)
        self.register_buffer("mean", torch.zeros(size))
        self.register_buffer("var", torch.ones(size))
        self.register_buffer("count", torch.tensor(1e-4, dtype=torch.float64))

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        return ((obs - self.mean) / (self.var + self.eps).sqrt()).clamp(-self.clip, self.clip)

    @torch.no_grad()
    def update(self, obs: torch.Tensor) -> None:
        """Add a batch of observations (..., size) to the statistics."""
        x = obs.reshape(-1, obs.shape[-1]).double()
        mean, var, count = merge_moments(
            self.mean.double(), self.var.double(), self.count, x.mean(0), x.var(0, correction=0), x.shape[0]
        )
        self.mean.copy_(mean)
        self.var.copy_(var)
        self.count.copy_(count)


class Normalized(nn.Module):
    """`module` on observations put through `obs_norm` first, which it uses but does not own (not
    a submodule: the statistics stay the actor's alone, in its state_dict and policy file, and a
    functional loss never copies them)."""

    def __init__(self, module: nn.Module, obs_norm: ObservationNorm):
        super().__init__()
        self.module = module
        object.__setattr__(self, "obs_norm", obs_norm)

    def forward(self, obs: torch.Tensor, *rest: torch.Tensor) -> torch.Tensor:
        return self.module(self.obs_norm(obs), *rest)


class RewardScale:
    """Baselines' VecNormalize on rewards: each env's discounted return ret <- gamma ret + r (reset
    at an episode's end) feeds a running variance, and rewards are divided by its square root and
    clipped to +-clip. Training only: its state is in the checkpoint, never in a policy file."""

    def __init__(self, num_envs: int, gamma: float, clip: float = 10.0, eps: float = 1e-8):
        self.gamma, self.clip, self.eps = float(gamma), float(clip), float(eps)
        self.ret = torch.zeros(num_envs, dtype=torch.float64)
        self.mean, self.var = torch.zeros((), dtype=torch.float64), torch.ones((), dtype=torch.float64)
        self.count = torch.tensor(1e-4, dtype=torch.float64)

    def __call__(self, reward: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Scaled rewards for a batch (envs, steps, ...) of `reward` and `done`; the statistics
        are updated with the batch's returns first (Baselines: with each step's, step by step)."""
        r = reward.reshape(reward.shape[0], reward.shape[1]).double()
        d = done.reshape(done.shape[0], done.shape[1])
        if r.shape[0] != self.ret.shape[0]:
            raise ValueError(f"RewardScale was built for {self.ret.shape[0]} envs, got a batch of {r.shape[0]}")
        returns = torch.empty_like(r)
        ret = self.ret
        for t in range(r.shape[1]):  # over the batch's steps (32), every env at once
            ret = ret * self.gamma + r[:, t]
            returns[:, t] = ret
            ret = torch.where(d[:, t], torch.zeros_like(ret), ret)
        self.ret = ret
        self.mean, self.var, self.count = merge_moments(
            self.mean, self.var, self.count, returns.mean(), returns.var(correction=0), returns.numel()
        )
        scaled = (r / (self.var + self.eps).sqrt()).clamp(-self.clip, self.clip)
        return scaled.to(reward.dtype).reshape(reward.shape)

    def state_dict(self) -> dict:
        return {k: getattr(self, k).clone() for k in ("ret", "mean", "var", "count")}

    def load_state_dict(self, state: dict) -> None:
        self.ret, self.mean = state["ret"].clone(), state["mean"].clone()
        self.var, self.count = state["var"].clone(), state["count"].clone()
