"""Controlled Starting State (CSS, paper sec. 4.2, eq. 18): practise where the agent is worst.

The (x, y) start area [-xy_range, xy_range]^2 is split into grid x grid equal squares. Each holds a
square value SV, updated when an episode that started in it ends:
    SV <- (SV + mean reward of that episode) / 2      (the first visit sets SV to that mean).
Episodes that end in the same square at the same step are averaged first, then applied once.

Starts pick a square with probability
    P = (1 - uniform) * softmax(-(SV - mean SV) / (temperature * (std SV + 1e-8))) + uniform / n,
so lower SV is favoured (the temperature is in units of the spread of SV, so it does not depend
on the reward's scale), no square starves (the uniform floor), and squares never visited count
as the worst visited one. Then a uniform point inside the square. CSS writes only x and y of
`"start_state"`; JD or the task distribution chooses the rest.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

from bfc import keys
from bfc.transforms._base import StartSampler, StepState, check


class ControlledStartingState(StartSampler):
    def __init__(
        self, num_envs: int, grid: int = 4, xy_range: float = 2.0, temperature: float = 1.0, uniform: float = 0.2
    ):
        super().__init__(num_envs)
        check(isinstance(grid, int) and grid >= 1, "css.grid", "an integer >= 1 (squares per side)", grid)
        check(math.isfinite(xy_range) and xy_range > 0, "env.start.xy_range", "> 0 with CSS on", xy_range)
        check(math.isfinite(temperature) and temperature > 0, "css.temperature", "> 0", temperature)
        check(0.0 <= uniform <= 1.0, "css.uniform", "in [0, 1]", uniform)
        self.grid, self.xy_range, self.temperature, self.uniform = grid, float(xy_range), float(temperature), uniform
        n_sq = grid * grid
        self.register_buffer("values", torch.zeros(n_sq))  # SV, row-major: index = iy * grid + ix
        self.register_buffer("visited", torch.zeros(n_sq, dtype=torch.bool))
        self.register_buffer("episodes", torch.zeros(n_sq, dtype=torch.long))
        self.register_buffer("square", torch.full((num_envs,), -1, dtype=torch.long))  # where each env started
        self.register_buffer("reward_sum", torch.zeros(num_envs))
        self.register_buffer("length", torch.zeros(num_envs, dtype=torch.long))

    @property
    def value_grid(self) -> torch.Tensor:
        """(grid, grid) SV, rows = y from -xy_range up, columns = x; NaN where never visited."""
        v = torch.where(self.visited, self.values, float("nan"))
        return v.view(self.grid, self.grid)

    def probabilities(self) -> torch.Tensor:
        n_sq = self.grid * self.grid
        if not bool(self.visited.any()):
            return torch.full((n_sq,), 1.0 / n_sq)
        seen = self.values[self.visited]
        sv = torch.where(self.visited, self.values, seen.min())
        spread = seen.std(unbiased=False) if seen.numel() > 1 else torch.tensor(0.0)
        logits = -(sv - seen.mean()) / (self.temperature * (spread + 1e-8))
        return (1 - self.uniform) * torch.softmax(logits, 0) + self.uniform / n_sq

    def fill_starts(self, start: torch.Tensor, mask: torch.Tensor) -> None:
        n = self.num_envs
        sq = torch.multinomial(self.probabilities(), n, replacement=True, generator=self.generator)
        ix, iy = sq % self.grid, sq // self.grid
        side = 2 * self.xy_range / self.grid
        u = self.rand(n, 2)
        x = -self.xy_range + (ix + u[:, 0]) * side
        y = -self.xy_range + (iy + u[:, 1]) * side
        start[:, 0] = torch.where(mask, x, start[:, 0])
        start[:, 1] = torch.where(mask, y, start[:, 1])
        self.square.copy_(torch.where(mask, sq, self.square))
        self.reward_sum.masked_fill_(mask, 0.0)
        self.length.masked_fill_(mask, 0)

    def update(self, squares: torch.Tensor, mean_rewards: torch.Tensor) -> None:
        """Apply eq. 18 for episodes (one entry each) that started in `squares` and just ended."""
        n_sq = self.grid * self.grid
        sums = torch.zeros(n_sq).index_add_(0, squares, mean_rewards.float())
        counts = torch.zeros(n_sq).index_add_(0, squares, torch.ones_like(mean_rewards, dtype=torch.float32))
        hit = counts > 0
        batch_mean = sums / counts.clamp(min=1)
        new = torch.where(self.visited, (self.values + batch_mean) / 2, batch_mean)
        self.values.copy_(torch.where(hit, new, self.values))
        self.visited |= hit
        self.episodes += counts.long()

    def advance(self, state: StepState) -> None:
        """The step's reward and end of episode (TDTS's included: it runs before CSS)."""
        self.count(state.reward, state.terminated | state.truncated)

    def count(self, reward: torch.Tensor, done: torch.Tensor) -> None:
        """One control step: add each env's reward (N,) to its episode; apply eq. 18 for the
        episodes that ended (`done` (N,) bool) in a square CSS chose."""
        self.reward_sum += reward
        self.length += 1
        ended = done & (self.square >= 0)
        if bool(ended.any()):
            self.update(self.square[ended], self.reward_sum[ended] / self.length[ended])
            self.square.masked_fill_(ended, -1)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        n, nxt = self.num_envs, next_tensordict
        state = StepState(reward=nxt.get(keys.REWARD).reshape(n))
        state.terminated, state.truncated = nxt.get(keys.TERMINATED).reshape(n), nxt.get(keys.TRUNCATED).reshape(n)
        self.advance(state)
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset
