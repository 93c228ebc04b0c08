"""The mirror loss (`loss.mirror_coeff`): the policy's mean in a mirrored world should be the mirror
of its mean (Yu et al. 2018, "Learning Symmetric and Low-Energy Locomotion"; rsl_rl's
`mirror_loss`).

Why: an "x" airframe flies the same in a mirror (x -> -x, y -> -y, or the half turn), yet PPO
learns a preferred way to turn over from upside down and takes the long way round from the
starts tilted the other way (the X500's seed 0 recovers 0.46 of development starts tilted over
150 deg with the pitch positive, 0.90 with it negative). With the loss the lean goes and the
policy hovers closer wherever something pushes it (docs/airframes.md, "X500: the mirror loss" and
"Crazyflie: the mirror loss"). The loss is the mean square of mean(M s) - P mean(s) over every
reflection the airframe has (AirframeParams.reflections), the mirrored side alone moved (the
target is held), as rsl_rl does; it changes training only: the network, the policy file and the
exports are as before. Two cheaper forms (docs/training.md): one reflection a row
(`loss.mirror_reflections=one`; no built-in keeps it) and the loss from `loss.mirror_from_frames`
on (PPO.update; the X500's from 1M frames). `loss.mirror_max_tilt` leaves the rows tilted more than
that from upright out: there a mirror-symmetric policy has no side to turn over to.
"""

from __future__ import annotations

import math

import torch

from bfc.envs.params import AirframeParams
from bfc.transforms.observation import cos_tilt, mirror_map


class Mirrors:
    """Every reflection of an airframe, as index-and-sign maps over the policy's observation and
    index maps over its four actions. `one`: each row is mirrored through one reflection, the
    reflections in turn by the row's place in the batch (`loss.mirror_reflections=one`), not
    through all of them: the same loss in expectation at a third of the mirrored rows of an "x"."""

    def __init__(self, airframe: AirframeParams, model, coeff: float, one: bool = False, max_tilt: float = 180.0):
        self.coeff, self.one = float(coeff), bool(one)
        self.kind, self.max_tilt = model.observation, float(max_tilt)
        maps = [
            (
                *mirror_map(
                    model.observation,
                    model.include_acceleration,
                    model.position_integral,
                    model.command_history,
                    sx,
                    sy,
                    motors,
                ),
                torch.tensor(motors),
            )
            for sx, sy, motors in airframe.reflections()
        ]
        self.index, self.sign, self.motors = (torch.stack(parts) for parts in zip(*maps, strict=True))

    def __len__(self) -> int:
        return len(self.motors)

    def reflection(self, rows: torch.Tensor) -> torch.Tensor | None:
        """The reflection each of the batch's `rows` (their places in it) is mirrored through, or
        None (every reflection)."""
        return rows % len(self) if self.one else None

    def kept(self, obs: torch.Tensor) -> torch.Tensor | None:
        """(n,) 1 for the raw observations `obs` (n, size) the loss holds (tilted at most max_tilt
        from upright), 0 for the others; None: every row (max_tilt 180)."""
        if self.max_tilt >= 180:
            return None
        return (cos_tilt(obs, self.kind) >= math.cos(math.radians(self.max_tilt))).to(obs.dtype)

    def observations(self, obs: torch.Tensor, reflection: torch.Tensor | None = None) -> torch.Tensor:
        """(m, n, size): `obs` (n, size) seen in each of the m mirrors; with `reflection` (n,),
        (1, n, size): each row in its own."""
        if reflection is None:
            return obs[:, self.index].mul(self.sign).transpose(0, 1)
        return obs.gather(1, self.index[reflection]).mul(self.sign[reflection]).unsqueeze(0)

    def actions(self, loc: torch.Tensor, reflection: torch.Tensor | None = None) -> torch.Tensor:
        """(m, n, 4): the actions `loc` (n, 4) in each mirror; with `reflection`, (1, n, 4)."""
        if reflection is None:
            return loc[:, self.motors].transpose(0, 1)
        return loc.gather(1, self.motors[reflection]).unsqueeze(0)

    def loss(self, loc, mirrored_loc, reflection=None, kept=None) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss, d loss / d mirrored_loc): coeff * mean square of `mirrored_loc` (m, n, 4), the means
        on the mirrored observations, against the mirror of `loc` (n, 4), held; `kept` (n,), from
        Mirrors.kept, zeroes the rows the loss does not hold (the mean still over all n)."""
        diff = mirrored_loc - self.actions(loc.detach(), reflection)
        if kept is not None:
            diff = diff * kept.unsqueeze(-1)
        return self.coeff * diff.square().mean(), diff * (2 * self.coeff / diff.numel())


def make_mirrors(cfg) -> Mirrors | None:
    """The run's mirrors, or None when `loss.mirror_coeff` is 0."""
    coeff = float(cfg.loss.mirror_coeff)
    if coeff == 0:
        return None
    from omegaconf import OmegaConf

    airframe = AirframeParams(**OmegaConf.to_container(cfg.env.airframe, resolve=True))
    one = cfg.loss.mirror_reflections == "one"
    return Mirrors(airframe, cfg.model, coeff, one, float(cfg.loss.mirror_max_tilt))
