"""The mirror loss (`loss.mirror_coeff`): the policy's mean in a mirrored world should be the mirror
of its mean (Yu et al. 2018, "Learning Symmetric and Low-Energy Locomotion"; rsl_rl's
`mirror_loss`).

Why: an "x" airframe flies the same in a mirror (x -> -x, y -> -y, or the half turn), yet PPO
learns a preferred way to turn over from upside down and takes the long way round from the
starts tilted the other way (the X500's seed 0 recovers 0.46 of development starts tilted over
150 deg with the pitch positive, 0.90 with it negative). With the loss the lean goes and the
policy hovers closer wherever something pushes it (docs/airframes.md, "X500: the mirror loss" and
"Crazyflie: the mirror loss"). The loss is the mean
square of mean(M s) - P mean(s) over every reflection the airframe has (AirframeParams.reflections),
the mirrored side alone moved (the target is held), as rsl_rl does; it changes training only:
the network, the policy file and the exports are as before.
"""

from __future__ import annotations

import torch

from bfc.envs.params import AirframeParams
from bfc.transforms.observation import mirror_map


class Mirrors:
    """Every reflection of an airframe, as index-and-sign maps over the policy's observation and
    index maps over its four actions."""

    def __init__(self, airframe: AirframeParams, model, coeff: float):
        self.coeff = float(coeff)
        self.maps = []
        for sx, sy, motors in airframe.reflections():
            index, sign = mirror_map(
                model.observation,
                model.include_acceleration,
                model.position_integral,
                model.command_history,
                sx,
                sy,
                motors,
            )
            self.maps.append((index, sign, torch.tensor(motors)))

    def __len__(self) -> int:
        return len(self.maps)

    def observations(self, obs: torch.Tensor) -> torch.Tensor:
        """(m, n, size): `obs` (n, size) seen in each of the m mirrors."""
        return torch.stack([obs[:, index] * sign for index, sign, _ in self.maps])

    def actions(self, loc: torch.Tensor) -> torch.Tensor:
        """(m, n, 4): the actions `loc` (n, 4) in each mirror."""
        return torch.stack([loc[:, motors] for _, _, motors in self.maps])

    def loss(self, loc: torch.Tensor, mirrored_loc: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """(loss, d loss / d mirrored_loc): coeff * mean square of `mirrored_loc` (m, n, 4), the means
        on the mirrored observations, against the mirror of `loc` (n, 4), held."""
        diff = mirrored_loc - self.actions(loc.detach())
        return self.coeff * diff.square().mean(), diff * (2 * self.coeff / diff.numel())


def make_mirrors(cfg) -> Mirrors | None:
    """The run's mirrors, or None when `loss.mirror_coeff` is 0."""
    coeff = float(cfg.loss.mirror_coeff)
    if coeff == 0:
        return None
    from omegaconf import OmegaConf

    airframe = AirframeParams(**OmegaConf.to_container(cfg.env.airframe, resolve=True))
    return Mirrors(airframe, cfg.model, coeff)
