"""The policy network and its Gaussian: one class that samples, scores and exports.

`GaussianActor` maps an observation to the mean of a diagonal Gaussian over the four motor
actions and holds a learned, state-independent std per motor. Its `sample`, `log_prob`,
`entropy` and `kl` are the only Gaussian arithmetic in bfc: PPO's step, TRPO, DDPG's
exploration, the collectors and the exports all call them. TorchRL's `ProbabilisticActor`
(`torchrl_actor`) wraps the same module for TorchRL's losses and collector; `gaussian_net` is the
one place that knows how it is nested.
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModule, TensorDictModuleBase
from tensordict.nn.probabilistic import interaction_type
from torch import nn
from torchrl.modules import MLP, IndependentNormal, ProbabilisticActor, ValueOperator

from bfc import keys
from bfc.agent.normalization import Normalized, ObservationNorm

ACTIVATIONS = dict(zip(keys.ACTIVATION_NAMES, (nn.Tanh, nn.ReLU, nn.ELU), strict=True))
_LOG_SQRT_2PI = math.log(math.sqrt(2 * math.pi))


class GaussianActor(nn.Module):
    """obs -> (loc, scale): an MLP mean and a learned, state-independent std per motor.

    The last layer starts near zero, so the untrained policy commands about hover (action 0);
    the std starts at `init_std` (small: big motor noise makes take-off a lottery) and, with
    `max_std`, never exceeds it (under latency PPO widens a free std; capping it did not save
    those runs, a KL target on the step did: docs/training.md, "Latency in training").
    squash=True puts the mean through tanh (inside [-1, 1]): for DDPG, whose actor climbs the
    critic's gradient and would otherwise leave the action range. normalize=True puts the
    observation through running statistics first (`obs_norm`, bfc.agent.normalization; the paper
    preset's Baselines-style normalisation), which the state_dict, and so a policy file, carries.
    """

    def __init__(
        self,
        obs_size: int,
        hidden,
        activation: str = "relu",
        init_std: float = 0.2,
        squash: bool = False,
        normalize: bool = False,
        max_std: float | None = None,
    ):
        super().__init__()
        self.squash = bool(squash)
        self.max_log_std = None if max_std is None else math.log(max_std)
        self.obs_norm = ObservationNorm(obs_size) if normalize else None
        self.mlp = MLP(
            in_features=obs_size, out_features=4, num_cells=list(hidden), activation_class=ACTIVATIONS[activation]
        )
        last = self.mlp[-1]
        with torch.no_grad():
            last.weight.mul_(0.01)
            last.bias.zero_()
        self.log_std = nn.Parameter(torch.full((4,), math.log(init_std)))

    @property
    def obs_size(self) -> int:
        return self.mlp[0].in_features

    def _mlp(self, obs: torch.Tensor) -> torch.Tensor:
        return self.mlp(obs if self.obs_norm is None else self.obs_norm(obs))

    def forward(self, obs: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self._mlp(obs)
        if self.squash:
            loc = loc.tanh()
        return loc, self.std.expand_as(loc)

    @property
    def std(self) -> torch.Tensor:
        """The Gaussian's std per motor (4,): the learned one, capped at `max_std` when set."""
        log_std = self.log_std if self.max_log_std is None else self.log_std.clamp(max=self.max_log_std)
        return log_std.exp()

    def mean(self, obs: torch.Tensor) -> torch.Tensor:
        """The deterministic action: the Gaussian's mean (`forward`'s loc, without the scale)."""
        loc = self._mlp(obs)
        return loc.tanh() if self.squash else loc

    def sample(self, obs: torch.Tensor):
        """(action, log_prob, loc, scale): a draw from torch's global generator, as
        `torch.distributions.Normal.rsample` draws it."""
        loc, scale = self(obs)
        action = loc + torch.empty_like(loc).normal_() * scale
        return action, self.log_prob(action, loc, scale), loc, scale

    @staticmethod
    def log_prob(action: torch.Tensor, loc: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
        """log N(action; loc, scale), summed over the four motors (`Normal.log_prob` arithmetic)."""
        return (-((action - loc) ** 2) / (2 * scale**2) - scale.log() - _LOG_SQRT_2PI).sum(-1)

    @staticmethod
    def entropy(scale: torch.Tensor) -> torch.Tensor:
        """The Gaussian's entropy, summed over the four motors."""
        return (0.5 + 0.5 * math.log(2 * math.pi) + scale.log()).sum(-1)

    @staticmethod
    def kl(loc0, scale0, loc1, scale1) -> torch.Tensor:
        """KL(N(loc0, scale0) || N(loc1, scale1)), summed over the four motors (`kl_divergence`'s)."""
        var_ratio = (scale0 / scale1).pow(2)
        t1 = ((loc0 - loc1) / scale1).pow(2)
        return (0.5 * (var_ratio + t1 - 1 - var_ratio.log())).sum(-1)


def torchrl_actor(net: GaussianActor, action_spec=None) -> ProbabilisticActor:
    """TorchRL's view of `net` (shared parameters): `"observation"` -> `"loc"`, `"scale"`,
    `"action"` and its log-probability, for TorchRL's losses and its Collector."""
    head = TensorDictModule(net, in_keys=[keys.OBSERVATION], out_keys=["loc", "scale"])
    return ProbabilisticActor(
        head,
        in_keys=["loc", "scale"],
        out_keys=[keys.ACTION],
        spec=action_spec,
        distribution_class=IndependentNormal,
        return_log_prob=True,
        default_interaction_type="random",
    )


def gaussian_net(module) -> GaussianActor | None:
    """The GaussianActor inside `module` (itself, or a `torchrl_actor` around it), else None."""
    if isinstance(module, GaussianActor):
        return module
    if isinstance(module, ProbabilisticActor):
        head = module.module[0]
        if isinstance(head, TensorDictModule) and isinstance(head.module, GaussianActor):
            return head.module
    return None


class SamplingActor(TensorDictModuleBase):
    """The actor's TensorDict interface for TorchRL's Collector and flight loops, in plain torch
    on the same GaussianActor (shared parameters): the ProbabilisticActor's outputs bit for bit
    (tests/training/test_hot_path.py) without building a Distribution per call. Under a
    deterministic exploration type the action is the mean, as the actor's."""

    def __init__(self, net: GaussianActor, log_prob_key: str = "action_log_prob"):
        super().__init__()
        self.net = net
        self.log_prob_key = log_prob_key
        self.in_keys = [keys.OBSERVATION]
        self.out_keys = ["loc", "scale", keys.ACTION, self.log_prob_key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        mode = interaction_type()
        if mode in (InteractionType.DETERMINISTIC, InteractionType.MEAN, InteractionType.MODE):
            loc, scale = self.net(tensordict.get(keys.OBSERVATION))
            action, log_prob = loc, self.net.log_prob(loc, loc, scale)
        elif mode is InteractionType.MEDIAN:  # as the actor: IndependentNormal has no median
            raise NotImplementedError("the Gaussian actor has no median interaction type")
        else:  # RANDOM or unset (the actor's default): torch.distributions.Normal.rsample
            action, log_prob, loc, scale = self.net.sample(tensordict.get(keys.OBSERVATION))
        tensordict.set("loc", loc)
        tensordict.set("scale", scale)
        tensordict.set(keys.ACTION, action)
        tensordict.set(self.log_prob_key, log_prob)
        return tensordict


def make_critic(obs_size: int, hidden, activation: str = "relu", obs_norm: nn.Module | None = None) -> ValueOperator:
    """V(s): an MLP on the observation (training only; never part of a policy file); with
    `obs_norm` (the actor's ObservationNorm, shared) on the normalised observation."""
    net = MLP(in_features=obs_size, out_features=1, num_cells=list(hidden), activation_class=ACTIVATIONS[activation])
    if obs_norm is not None:
        net = Normalized(net, obs_norm)
    return ValueOperator(net, in_keys=[keys.OBSERVATION])
