"""Actor and critic networks, and the deployable policy file (`policy.pt`).

A policy file is data, never code: a dict of tensors, numbers and strings that loads with
`torch.load(path, weights_only=True)`. It records the network shape and the env settings the
policy was trained with (control rate, airframe, observation), so it is always flown as trained.
"""

from __future__ import annotations

import math
from pathlib import Path

import torch
from tensordict import TensorDictBase
from tensordict.nn import InteractionType, TensorDictModule, TensorDictModuleBase
from tensordict.nn.probabilistic import interaction_type
from torch import nn
from torchrl.modules import MLP, IndependentNormal, ProbabilisticActor, ValueOperator

from bfc import keys

POLICY_FORMAT = "bfc-policy-v1"
ACTIVATIONS = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU}


class GaussianHead(nn.Module):
    """obs -> (loc, scale): an MLP mean and a learned, state-independent std per motor.

    The last layer starts near zero, so the untrained policy commands about hover (action 0);
    the std starts at `init_std` (small: big motor noise makes take-off a lottery).
    squash=True puts the mean through tanh (inside [-1, 1]): for DDPG, whose actor climbs the
    critic's gradient and would otherwise leave the action range.
    """

    def __init__(
        self, obs_size: int, hidden: list[int], activation: str = "tanh", init_std: float = 0.2, squash: bool = False
    ):
        super().__init__()
        self.squash = bool(squash)
        self.mean = MLP(
            in_features=obs_size, out_features=4, num_cells=list(hidden), activation_class=ACTIVATIONS[activation]
        )
        last = self.mean[-1]
        with torch.no_grad():
            last.weight.mul_(0.01)
            last.bias.zero_()
        self.log_std = nn.Parameter(torch.full((4,), math.log(init_std)))

    def forward(self, obs: torch.Tensor):
        loc = self.mean(obs)
        if self.squash:
            loc = loc.tanh()
        return loc, self.log_std.exp().expand_as(loc)


def make_actor(
    obs_size: int, hidden, activation="tanh", init_std=0.2, action_spec=None, squash=False
) -> ProbabilisticActor:
    head = TensorDictModule(
        GaussianHead(obs_size, list(hidden), activation, init_std, squash),
        in_keys=[keys.OBSERVATION],
        out_keys=["loc", "scale"],
    )
    return ProbabilisticActor(
        head,
        in_keys=["loc", "scale"],
        out_keys=[keys.ACTION],
        spec=action_spec,
        distribution_class=IndependentNormal,
        return_log_prob=True,
        default_interaction_type="random",
    )


def is_gaussian_actor(module) -> bool:
    """Whether `module` is an actor `make_actor` built (a GaussianHead inside a ProbabilisticActor)."""
    return (
        isinstance(module, ProbabilisticActor)
        and isinstance(module.module[0], TensorDictModule)
        and isinstance(module.module[0].module, GaussianHead)
    )


class SamplingActor(TensorDictModuleBase):
    """The actor's sampling path for the collector, in plain torch ops on the same GaussianHead
    (shared parameters): the ProbabilisticActor's outputs bit for bit (the same normal draw from
    torch's generator, the same log-prob arithmetic; tests/training/test_hot_path.py) without building a
    Distribution and the TensorDict plumbing around it on every step (1.06 -> 0.39 ms a call at
    256 envs, measured in isolation). Under a deterministic exploration type the action is the mean, as the actor's."""

    def __init__(self, actor: ProbabilisticActor):
        super().__init__()
        self.head = actor.module[0].module
        self.log_prob_key = actor.module[-1].log_prob_key
        self.in_keys = [keys.OBSERVATION]
        self.out_keys = ["loc", "scale", keys.ACTION, self.log_prob_key]

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        loc, scale = self.head(tensordict.get(keys.OBSERVATION))
        mode = interaction_type()
        if mode in (InteractionType.DETERMINISTIC, InteractionType.MEAN, InteractionType.MODE):
            action = loc
        elif mode is InteractionType.MEDIAN:  # as the actor: IndependentNormal has no median
            raise NotImplementedError("the Gaussian actor has no median interaction type")
        else:  # RANDOM or unset (the actor's default): torch.distributions.Normal.rsample
            action = loc + torch.empty_like(loc).normal_() * scale
        # torch.distributions.Normal.log_prob, summed over the 4 motors (Independent)
        log_prob = -((action - loc) ** 2) / (2 * scale**2) - scale.log() - math.log(math.sqrt(2 * math.pi))
        tensordict.set("loc", loc)
        tensordict.set("scale", scale)
        tensordict.set(keys.ACTION, action)
        tensordict.set(self.log_prob_key, log_prob.sum(-1))
        return tensordict


def make_critic(obs_size: int, hidden, activation="tanh") -> ValueOperator:
    net = MLP(in_features=obs_size, out_features=1, num_cells=list(hidden), activation_class=ACTIVATIONS[activation])
    return ValueOperator(net, in_keys=[keys.OBSERVATION])


def save_policy(path, actor: ProbabilisticActor, *, model: dict, env: dict, observation: dict, info: dict) -> None:
    """Write a policy file atomically (write to a temporary name, then rename)."""
    head = actor.module[0].module
    payload = {
        "format": POLICY_FORMAT,
        "state_dict": {k: v.detach().clone() for k, v in head.state_dict().items()},
        "model": model,
        "env": env,
        "observation": observation,
        "info": info,
    }
    atomic_save(payload, path)


def atomic_save(obj, path) -> None:
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    torch.save(obj, tmp)
    tmp.replace(path)


def read_policy_file(path) -> dict:
    """Load and check a policy file (data only); clear errors for missing or foreign files."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no policy file at {path}: pass the path of a policy.pt written by train.py")
    try:
        payload = torch.load(path, map_location="cpu", weights_only=True)
    except Exception as err:  # noqa: BLE001 - any unpickling failure means "not a policy file"
        raise ValueError(f"{path} is not a loadable bfc policy file (weights_only load failed: {err})") from None
    if not isinstance(payload, dict) or payload.get("format") != POLICY_FORMAT:
        raise ValueError(f"{path} is not a bfc policy file (expected format {POLICY_FORMAT!r})")
    return payload


def model_settings(payload: dict) -> dict:
    """The `model` config keys a policy file was trained with that decide how it is flown: its
    action map and its observation (the one reader for `fly` and the ONNX export)."""
    observation = payload["observation"]
    return {
        # files written before `action_map` existed used the speed map
        "action_map": str(payload["model"].get("action_map", "speed")),
        "include_acceleration": bool(observation["include_acceleration"]),
        "position_integral": bool(observation.get("position_integral", False)),
        "observation": str(observation.get("kind", "heading")),
    }


def load_policy(path) -> tuple[ProbabilisticActor, dict]:
    """(actor, payload): the actor in eval mode with the file's weights, and the file's settings."""
    payload = read_policy_file(path)
    m = payload["model"]
    actor = make_actor(
        payload["observation"]["size"], m["actor_hidden"], m["activation"], m["init_std"], squash=m.get("squash", False)
    )
    actor.module[0].module.load_state_dict(payload["state_dict"])
    actor.eval()
    return actor, payload


def export_onnx(policy_path, onnx_path, opset=None):
    """Write a policy file as an ONNX model (the deterministic policy with its observation and
    action maps inside); see bfc.export and docs/export.md. Needs the `onnx` extra."""
    from bfc.export import export_onnx as _export_onnx

    return _export_onnx(policy_path, onnx_path, opset=opset)
