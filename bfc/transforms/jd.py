"""Jumping Distribution (JD, paper sec. 4.1): start in the air with probability p(t), else on the ground.

p(t) starts at p0 and decays with the number of env steps collected (all envs counted) to exactly
`p_end` (0 in the paper) at `decay_frames`, and stays there. The counter is a buffer, so it
survives checkpoint/resume.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase

from bfc.envs.params import JDParams, as_params
from bfc.transforms._base import StartSampler, StepState, check


class JumpingDistribution(StartSampler):
    """Per reset env: with probability p(t) a JD start (z, attitude and optional velocities drawn
    from the configured ranges), else the task's ground start (left NaN for the env to draw from D).
    Ranges are in metres, degrees, m/s and deg/s.
    """

    def __init__(self, num_envs: int, params: JDParams | dict | None = None, **changes):
        """params: a JDParams (a mapping of its fields; None: the paper's values); `changes`: any
        of its fields by keyword, e.g. `JumpingDistribution(n, p_end=0.5)`."""
        super().__init__(num_envs)
        p = self.params = as_params(JDParams, params, **changes)
        check(p.decay_frames is not None, "jd.decay_frames", "an integer >= 0 (the run's frames resolved)", None)
        self.p0, self.p_end, self.schedule = p.p0, p.p_end, p.schedule
        self.decay_frames = int(p.decay_frames)
        lows, highs = [], []
        for (lo, hi), scale in (
            (p.z_range, 1.0),
            (p.roll_range, math.pi / 180),
            (p.pitch_range, math.pi / 180),
            (p.yaw_range, math.pi / 180),
        ):
            lows.append(lo * scale)
            highs.append(hi * scale)
        vlo, vhi = p.velocity_range
        wlo, whi = p.angular_velocity_range
        lows += [vlo] * 3 + [math.radians(wlo)] * 3
        highs += [vhi] * 3 + [math.radians(whi)] * 3
        self.register_buffer("low", torch.tensor(lows))
        self.register_buffer("high", torch.tensor(highs))
        # How much of the attitude and velocity ranges is drawn from (about their centres), in
        # [0, 1]: a training curriculum (bfc.collectors.curriculum) widens it to 1. Height and yaw
        # always take their whole ranges.
        self.range_scale = 1.0
        # Share of in-air starts mirrored upside down (tilt -> 180 deg - tilt), times `inverted_scale`
        # (the curriculum raises it from 0 to 1 with its progress; 1 without one). Near-inverted
        # starts are where the policy learns to flip before it thrusts (docs/training.md).
        self.inverted_share, self.inverted_scale = p.inverted_share, 1.0
        # Share of those upside-down starts released at rest (no velocity, no body rates): there
        # no initial spin says which way to turn over, the hardest flip (docs/training.md).
        self.inverted_at_rest = p.inverted_at_rest
        # Their drawn roll and pitch are scaled by this before the turn (from 1 to it with the
        # curriculum's progress), so they land nearer 180 deg (0.5: tilted at least about 120 deg),
        # where the any-attitude failures are; no extra draw.
        self.inverted_spread = p.inverted_spread
        self._widens = torch.tensor([0.0, 1, 1, 0, 1, 1, 1, 1, 1, 1])  # z, roll, pitch, yaw, v, w
        self.register_buffer("frames", torch.zeros((), dtype=torch.long))

    @property
    def probability(self) -> float:
        """p(t) at the current frame count."""
        return self.probability_at(int(self.frames))

    def probability_at(self, frames: int) -> float:
        if self.schedule == "constant":
            return self.p0
        if self.decay_frames == 0 or frames >= self.decay_frames:
            return self.p_end
        progress = frames / self.decay_frames
        if self.schedule == "linear":
            return self.p0 * (1.0 - progress) + self.p_end * progress
        weight = 0.5 * (1.0 + math.cos(math.pi * progress))
        return self.p0 * weight + self.p_end * (1.0 - weight)

    def fill_starts(self, start: torch.Tensor, mask: torch.Tensor) -> None:
        air = mask & (self.rand(self.num_envs) < self.probability)
        centre, half = (self.low + self.high) / 2, (self.high - self.low) / 2
        half = half * (1 - self._widens * (1 - self.range_scale))
        drawn = centre - half + 2 * half * self.rand(self.num_envs, 10)  # z, rpy, v, w
        share = self.inverted_share * self.inverted_scale
        if share > 0:  # drawn only when asked, so runs without it keep their random streams
            roll, pitch = drawn[:, 1], drawn[:, 2]
            upright = torch.cos(roll) * torch.cos(pitch) > 0
            flip = upright & (self.rand(self.num_envs) < share)
            # roll + pi negates cos(roll) cos(pitch), the body z axis's vertical component; roll and
            # pitch times k first turn the start nearer 180 deg (k = 1: as drawn, bit for bit)
            k = 1 - (1 - self.inverted_spread) * self.inverted_scale  # narrows with the curriculum, too
            drawn[:, 1] = torch.where(flip, torch.remainder(k * roll + 2 * math.pi, 2 * math.pi) - math.pi, roll)
            drawn[:, 2] = torch.where(flip, k * pitch, pitch)
            if self.inverted_at_rest > 0:  # again drawn only when asked
                still = flip & (self.rand(self.num_envs) < self.inverted_at_rest)
                drawn[:, 4:] = torch.where(still.unsqueeze(-1), 0.0, drawn[:, 4:])
        start[:, 2:12] = torch.where(air.unsqueeze(-1), drawn, start[:, 2:12])

    def advance(self, state: StepState) -> None:
        """One control step of every env: p(t) counts it."""
        self.frames += self.num_envs

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        self.advance(StepState())
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset
