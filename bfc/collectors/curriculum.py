"""A difficulty curriculum: the training world widens from an easy start to the configured one.

`curriculum.frames` > 0 scales, at every batch, JD's attitude and velocity ranges (about their
centres) and the `env.randomize` ranges (towards the nominal airframe, the wind towards 0) by

    s(frames) = start + (1 - start) * min(1, frames / curriculum.frames)

so early episodes start near level and at rest on a nearly nominal airframe, where PPO first
learns to hover, and the recoveries from any attitude on any airframe come once it flies. With
`latency.curriculum` the latency transforms' delays grow with the progress min(1, frames /
curriculum.frames), from none at the first frame to the configured ones. The
scale is a function of the frame count alone, so a resumed run sets the same scale it had.
"""

from __future__ import annotations


class Curriculum:
    def __init__(self, cfg, env, jd=None, delays=()):
        c = cfg.curriculum
        self.frames, self.start = int(c.frames), float(c.start)
        self.base_env, self.jd = env.base_env, jd
        self.delays = list(delays) if cfg.latency.curriculum else []

    def progress(self, frames: int) -> float:
        """How far the curriculum is, 0 to 1 (1 without one): JD's upside-down share grows with it."""
        return 1.0 if self.frames <= 0 else min(1.0, frames / self.frames)

    def scale(self, frames: int) -> float:
        return self.start + (1.0 - self.start) * self.progress(frames)

    def apply(self, frames: int) -> float:
        """Set the scale for the batch that starts at `frames`; returns it."""
        s = self.scale(frames)
        self.base_env.randomize_scale = s
        if self.jd is not None:
            self.jd.range_scale = s
            self.jd.inverted_scale = self.progress(frames)
        for delay in self.delays:
            delay.range_scale = self.progress(frames)
        return s
