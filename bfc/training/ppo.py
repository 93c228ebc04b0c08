"""PPO: the losses (clipped, eq. 11, or adaptive KL penalty, eq. 12), GAE (eq. 15) and the update;
the learner interface every algorithm shares (`make_learner`: ppo here, trpo.py, ddpg.py)."""

from __future__ import annotations

import torch
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
        self.optimizer = torch.optim.Adam(self.loss_module.parameters(), lr=cfg.optim.lr)
        self.optimizers = [self.optimizer]

    def update(self, data: TensorDictBase) -> dict[str, float]:
        return ppo_update(data, self.loss_module, self.advantage, self.optimizer, self.cfg)

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


def ppo_update(data: TensorDictBase, loss_module, advantage, optimizer, cfg) -> dict[str, float]:
    """GAE once per batch (as CleanRL), then `loss.epochs` passes in shuffled minibatches."""
    lo, params = cfg.loss, list(loss_module.parameters())
    sums: dict[str, float] = {}
    count = 0
    clip_fraction_seen = False
    size = minibatch_size(cfg)
    compute_advantage(data, advantage)
    flat = data.select(*_LOSS_KEYS, strict=False).reshape(-1)
    for _ in range(lo.epochs):
        perm = torch.randperm(flat.shape[0])
        for start in range(0, flat.shape[0], size):
            batch = flat[perm[start : start + size]]
            out = loss_module(batch)
            total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", 0.0)
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            torch.nn.utils.clip_grad_norm_(params, cfg.optim.max_grad_norm)
            optimizer.step()
            for key, tag in LOSS_TAGS.items():
                if key in out.keys():
                    sums[tag] = sums.get(tag, 0.0) + float(out[key].detach().mean())
                    clip_fraction_seen |= key == "clip_fraction"
            count += 1
    metrics = {tag: value / count for tag, value in sums.items()}
    if not clip_fraction_seen:  # the KL-penalty loss has no clipping
        metrics["loss/clip_fraction"] = 0.0
    if isinstance(loss_module, KLPENPPOLoss):
        metrics["loss/kl_beta"] = float(loss_module.beta)
    return metrics
