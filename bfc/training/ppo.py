"""PPO: the losses (clipped, eq. 11, or adaptive KL penalty, eq. 12), GAE (eq. 15) and the update;
the learner interface every algorithm shares (`make_learner`: ppo here, trpo.py, ddpg.py)."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F
from tensordict import TensorDictBase
from torchrl.objectives import ClipPPOLoss, KLPENPPOLoss
from torchrl.objectives.value import GAE

from bfc import keys
from bfc.config import ALGORITHMS, minibatch_size
from bfc.policy import make_actor, make_critic

# What the loss reads; selecting these first makes every minibatch gather cheaper.
_LOSS_KEYS = (
    keys.OBSERVATION,
    keys.ACTION,
    "action_log_prob",
    "loc",
    "scale",
    "advantage",
    "value_target",
    "state_value",
)

LOSS_TAGS = {
    "loss_objective": "loss/objective",
    "loss_critic": "loss/critic",
    "entropy": "loss/entropy",
    "kl_approx": "loss/approx_kl",
    "clip_fraction": "loss/clip_fraction",
}


class FusedClipLoss:
    """ClipPPOLoss's forward (eq. 11's clipped surrogate on per-minibatch standardised advantages,
    the L2 critic loss, the entropy term, the approximate KL and the clip fraction) in plain torch
    on the actor's GaussianHead and the critic's MLP: the same values and gradients as the
    ClipPPOLoss it is built from (tests/training/test_hot_path.py), without that module's
    per-call TensorDict and functional-parameter plumbing, which costs more than the networks
    themselves at the small minibatches bfc trains with (bench/update_time.py)."""

    def __init__(self, loss: ClipPPOLoss, actor, critic):
        self.head, self.value = actor.module[0].module, critic.module
        epsilon = loss.clip_epsilon.detach().clone()
        self.low, self.high = (-epsilon).log1p(), epsilon.log1p()  # ClipPPOLoss's bounds on log(ratio)
        self.critic_coeff = loss.critic_coeff.detach().clone()
        self.entropy_coeff = float(loss.entropy_coeff)
        self.eps = torch.finfo(torch.float).resolution  # torchrl's advantage standardisation

    def __call__(self, obs, action, old_log_prob, advantage, value_target) -> dict[str, torch.Tensor]:
        advantage = (advantage - advantage.mean()) / advantage.std().clamp_min(self.eps)
        loc, scale = self.head(obs)
        log_scale = scale.log()
        log_prob = (-((action - loc) ** 2) / (2 * scale**2) - log_scale - math.log(math.sqrt(2 * math.pi))).sum(-1)
        log_weight = (log_prob - old_log_prob).unsqueeze(-1)
        clipped = log_weight.clamp(self.low, self.high)
        gain = torch.minimum(log_weight.exp() * advantage, clipped.exp() * advantage)
        entropy = (0.5 + 0.5 * math.log(2 * math.pi) + log_scale).sum(-1, keepdim=True)
        critic = F.mse_loss(value_target, self.value(obs), reduction="none") * self.critic_coeff
        return {
            "loss_objective": -gain.mean(),
            "loss_critic": critic.mean(),
            "loss_entropy": (-self.entropy_coeff * entropy).mean(),
            "entropy": entropy.detach().mean(),
            "kl_approx": (old_log_prob - log_prob).detach().mean(),
            "clip_fraction": (clipped != log_weight).float().mean(),
        }


def make_models(cfg, obs_size: int, action_spec=None):
    m = cfg.model
    actor = make_actor(obs_size, m.actor_hidden, m.activation, m.init_std, action_spec=action_spec, squash=m.squash)
    critic = make_critic(obs_size, m.critic_hidden, m.activation)
    return actor, critic


def make_loss(cfg, actor, critic):
    lo = cfg.loss
    common = dict(
        entropy_coeff=lo.entropy_coeff, critic_coeff=lo.critic_coeff, loss_critic_type="l2", normalize_advantage=True
    )
    if lo.kind == "clip":
        loss = ClipPPOLoss(actor, critic, clip_epsilon=lo.clip_epsilon, **common)
    else:
        loss = KLPENPPOLoss(actor, critic, dtarg=lo.dtarg, **common)
    # GAE reads precomputed values (see compute_advantage): one plain critic pass per batch
    # instead of TorchRL's vmapped pass over observation and next observation per epoch.
    advantage = GAE(gamma=lo.gamma, lmbda=lo.lmbda, value_network=None, average_gae=False)
    advantage.critic = critic
    return loss, advantage


@torch.no_grad()
def compute_advantage(data: TensorDictBase, advantage) -> None:
    """Values of observation and next observation in one forward, then GAE (eq. 15) in place."""
    critic = advantage.critic
    obs = data.get(keys.OBSERVATION)
    both = critic.module(torch.cat((obs, data.get(("next", keys.OBSERVATION))), 0))
    value, next_value = both.split(obs.shape[0], 0)
    data.set("state_value", value)
    data.set(("next", "state_value"), next_value)
    advantage(data)


class PPO:
    """The PPO learner. Every learner (PPO, `trpo.TRPO`, `ddpg.DDPG`) has this interface:
    `update(data) -> metrics`, `optimizers` (the learning-rate anneal scales them all) and
    `state_dict()` / `load_state_dict()` (its part of a checkpoint)."""

    def __init__(self, cfg, actor, critic):
        self.cfg = cfg
        self.loss_module, self.advantage = make_loss(cfg, actor, critic)
        self.fused = FusedClipLoss(self.loss_module, actor, critic) if cfg.loss.kind == "clip" else None
        # fused: one kernel for every parameter's Adam step (0.25 against 1 ms a step here)
        self.optimizer = torch.optim.Adam(self.loss_module.parameters(), lr=cfg.optim.lr, fused=True)
        self.optimizers = [self.optimizer]

    def update(self, data: TensorDictBase) -> dict[str, float]:
        return ppo_update(data, self.loss_module, self.advantage, self.optimizer, self.cfg, self.fused)

    def state_dict(self) -> dict:
        return {"optimizer": self.optimizer.state_dict(), "loss": self.loss_module.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
        self.loss_module.load_state_dict(state["loss"], strict=False)


def make_learner(cfg, actor, critic):
    """The learner `algo.name` names (ppo, trpo, ddpg)."""
    name = cfg.algo.name
    if name == "ppo":
        return PPO(cfg, actor, critic)
    if name == "trpo":
        from bfc.training.trpo import TRPO

        return TRPO(cfg, actor, critic)
    if name == "ddpg":
        from bfc.training.ddpg import DDPG

        return DDPG(cfg, actor, critic)
    raise ValueError(f"algo.name must be one of {', '.join(ALGORITHMS)}, got {name!r}")


def ppo_update(data: TensorDictBase, loss_module, advantage, optimizer, cfg, fused=None) -> dict[str, float]:
    """GAE once per batch (as CleanRL), then `loss.epochs` passes in shuffled minibatches; with
    `fused` (a FusedClipLoss) each minibatch is plain tensors through it, else a TensorDict
    through `loss_module`."""
    lo, params = cfg.loss, list(loss_module.parameters())
    size = minibatch_size(cfg)
    compute_advantage(data, advantage)
    sums: dict[str, torch.Tensor] = {}
    if fused is not None:
        # one (frames, columns) table, so that a minibatch is one gather
        columns = [
            data.get(keys.OBSERVATION),
            data.get(keys.ACTION),
            data.get(loss_module.tensor_keys.sample_log_prob).unsqueeze(-1),
            data.get("advantage"),
            data.get("value_target"),
        ]
        widths = [c.shape[-1] for c in columns]
        table = torch.cat(columns, -1).reshape(data.numel(), -1)
        n = table.shape[0]

        def loss_of(index):
            obs, action, log_prob, adv, target = table[index].split(widths, -1)
            return fused(obs, action, log_prob.squeeze(-1), adv, target)
    else:
        flat = data.select(*_LOSS_KEYS, strict=False).reshape(-1)
        n = flat.shape[0]

        def loss_of(index):
            return loss_module(flat[index])

    count = 0
    for _ in range(lo.epochs):
        perm = torch.randperm(n)
        for start in range(0, n, size):
            out = loss_of(perm[start : start + size])
            total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", 0.0)
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            torch.nn.utils.clip_grad_norm_(params, cfg.optim.max_grad_norm)
            optimizer.step()
            for key, tag in LOSS_TAGS.items():
                if key in out.keys():
                    value = out[key].detach().mean()
                    sums[tag] = sums[tag] + value if tag in sums else value
            count += 1
    metrics = {tag: float(value) / count for tag, value in sums.items()}
    metrics.setdefault("loss/clip_fraction", 0.0)  # the KL-penalty loss has no clipping
    if isinstance(loss_module, KLPENPPOLoss):
        metrics["loss/kl_beta"] = float(loss_module.beta)
    return metrics
