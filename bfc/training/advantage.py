"""GAE (eq. 15) on a collected batch: TorchRL's estimator, fed precomputed values."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives.value import GAE

from bfc import keys


def make_gae(gamma: float, lmbda: float, critic) -> GAE:
    """TorchRL's GAE reading `"state_value"` from the batch (`compute_advantage` fills it): one
    plain critic pass per batch instead of TorchRL's vmapped pass per epoch."""
    advantage = GAE(gamma=gamma, lmbda=lmbda, value_network=None, average_gae=False)
    advantage.critic = critic
    return advantage


@torch.no_grad()
def compute_advantage(data: TensorDictBase, advantage: GAE) -> None:
    """Values of observation and next observation in one forward, then GAE in place
    (`"advantage"`, `"value_target"`)."""
    critic = advantage.critic
    obs = data.get(keys.OBSERVATION)
    both = critic.module(torch.cat((obs, data.get(("next", keys.OBSERVATION))), 0))
    value, next_value = both.split(obs.shape[0], 0)
    data.set("state_value", value)
    data.set(("next", "state_value"), next_value)
    advantage(data)
