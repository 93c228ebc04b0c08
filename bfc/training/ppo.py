"""PPO: the losses (clipped, eq. 11, or adaptive KL penalty, eq. 12) and the update. It reads the
`loss` section (and `optim`)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives import ClipPPOLoss, KLPENPPOLoss
from torchrl.objectives.utils import distance_loss

from bfc import keys
from bfc.agent import GaussianActor, gaussian_net
from bfc.config import minibatch_size
from bfc.training.advantage import compute_advantage, make_gae

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
    the critic loss of its `loss_critic_type`, the entropy term, the approximate KL and the clip
    fraction) in plain torch on the actor's GaussianActor and the critic's MLP: the same values and
    gradients as the ClipPPOLoss it is built from (tests/training/test_hot_path.py), without that
    module's per-call TensorDict and functional-parameter plumbing, which costs more than the
    networks themselves at the small minibatches bfc trains with (bench/update_time.py).
    Every option of the loss is read from it; one it does not implement is refused."""

    def __init__(self, loss: ClipPPOLoss, actor, critic):
        unsupported = {
            "separate_losses": loss.separate_losses or None,
            "advantage_norm": getattr(loss, "advantage_norm", None),
            "max_importance_ratio": getattr(loss, "max_importance_ratio", None),
        }
        used = [name for name, value in unsupported.items() if value is not None]
        if used or not loss.normalize_advantage:
            what = ", ".join(used) or "normalize_advantage=False"
            raise ValueError(f"the fused PPO loss does not implement ClipPPOLoss's {what}")
        self.net, self.value = gaussian_net(actor), critic.module
        epsilon = loss.clip_epsilon.detach().clone()
        self.low, self.high = (-epsilon).log1p(), epsilon.log1p()  # ClipPPOLoss's bounds on log(ratio)
        self.critic_coeff = loss.critic_coeff.detach().clone()
        self.clip_value = float(loss.clip_value) if loss.clip_value is not None else None
        self.critic_loss = loss.loss_critic_type
        self.entropy_coeff = float(loss.entropy_coeff)
        self.eps = torch.finfo(torch.float).resolution  # torchrl's advantage standardisation

    def __call__(self, obs, action, old_log_prob, advantage, value_target, old_value=None) -> dict[str, torch.Tensor]:
        advantage = (advantage - advantage.mean()) / advantage.std().clamp_min(self.eps)
        loc, scale = self.net(obs)
        log_prob = GaussianActor.log_prob(action, loc, scale)
        log_weight = (log_prob - old_log_prob).unsqueeze(-1)
        clipped = log_weight.clamp(self.low, self.high)
        gain = torch.minimum(log_weight.exp() * advantage, clipped.exp() * advantage)
        entropy = GaussianActor.entropy(scale).unsqueeze(-1)
        value = self.value(obs)
        critic = distance_loss(value_target, value, self.critic_loss)
        if self.clip_value is not None:  # ClipPPOLoss's clip_value: the more pessimistic of the two
            near = old_value + (value - old_value).clamp(-self.clip_value, self.clip_value)
            critic = torch.maximum(critic, distance_loss(value_target, near, self.critic_loss))
        critic = critic * self.critic_coeff
        return {
            "loss_objective": -gain.mean(),
            "loss_critic": critic.mean(),
            "loss_entropy": (-self.entropy_coeff * entropy).mean(),
            "entropy": entropy.detach().mean(),
            "kl_approx": (old_log_prob - log_prob).detach().mean(),
            "clip_fraction": (clipped != log_weight).float().mean(),
        }


def make_loss(cfg, actor, critic):
    """TorchRL's ClipPPOLoss (or KLPENPPOLoss) and GAE from the `loss` section."""
    lo = cfg.loss
    common = dict(
        entropy_coeff=lo.entropy_coeff,
        critic_coeff=lo.critic_coeff,
        loss_critic_type=lo.critic_loss,
        normalize_advantage=True,
        clip_value=lo.clip_value,
    )
    if lo.kind == "clip":
        loss = ClipPPOLoss(actor, critic, clip_epsilon=lo.clip_epsilon, **common)
    else:
        loss = KLPENPPOLoss(actor, critic, dtarg=lo.dtarg, **common)
    return loss, make_gae(lo.gamma, lo.lmbda, critic)


class PPO:
    """The PPO learner (the interface of bfc.training.learners)."""

    def __init__(self, cfg, actor, critic):
        self.cfg = cfg
        self.loss_module, self.advantage = make_loss(cfg, actor, critic)
        self.fused = FusedClipLoss(self.loss_module, actor, critic) if cfg.loss.kind == "clip" else None
        # fused: one kernel for every parameter's Adam step (0.25 against 1 ms a step here)
        self.optimizer = torch.optim.Adam(
            self.loss_module.parameters(), lr=cfg.optim.lr, eps=cfg.optim.adam_eps, fused=True
        )
        self.optimizers = [self.optimizer]

    def update(self, data: TensorDictBase) -> dict[str, float]:
        return ppo_update(data, self.loss_module, self.advantage, self.optimizer, self.cfg, self.fused)

    def state_dict(self) -> dict:
        return {"optimizer": self.optimizer.state_dict(), "loss": self.loss_module.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
        self.loss_module.load_state_dict(state["loss"], strict=False)


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
        if fused.clip_value is not None:  # the collected value, which ClipPPOLoss's clip_value keeps the new one near
            columns.append(data.get("state_value"))
        widths = [c.shape[-1] for c in columns]
        table = torch.cat(columns, -1).reshape(data.numel(), -1)
        n = table.shape[0]

        def loss_of(index):
            obs, action, log_prob, adv, target, *old_value = table[index].split(widths, -1)
            return fused(obs, action, log_prob.squeeze(-1), adv, target, *old_value)
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
