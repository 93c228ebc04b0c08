"""PPO: the losses (clipped, eq. 11, or adaptive KL penalty, eq. 12) and the update. It reads the
`loss` section (and `optim`)."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.objectives import ClipPPOLoss, KLPENPPOLoss

from bfc import keys
from bfc.agent import gaussian_net
from bfc.config import minibatch_size
from bfc.training.advantage import compute_advantage, make_gae
from bfc.training.mirror import make_mirrors
from bfc.training.ppo_step import PPOStep

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
    "mirror": "loss/mirror",
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
    """The PPO learner (the interface of bfc.training.learners): the clipped loss through bfc's
    own step (`loss.implementation=bfc`, bfc.training.ppo_step) or TorchRL's loss module and
    torch's Adam (`torchrl`, and always for the KL-penalty loss)."""

    def __init__(self, cfg, actor, critic):
        self.cfg = cfg
        self.loss_module, self.advantage = make_loss(cfg, actor, critic)
        self.mirrors, self.actor_net = make_mirrors(cfg), gaussian_net(actor)
        o = cfg.optim
        if cfg.loss.kind == "clip" and cfg.loss.implementation == "bfc":
            self.step = PPOStep(self.loss_module, actor, critic, o.lr, o.adam_eps, o.max_grad_norm, self.mirrors)
            self.optimizer = self.step.optimizer
        else:
            self.step = None
            # fused: one kernel for every parameter's Adam step (0.25 against 1 ms a step here)
            self.optimizer = torch.optim.Adam(self.loss_module.parameters(), lr=o.lr, eps=o.adam_eps, fused=True)
        self.optimizers = [self.optimizer]

    def update(self, data: TensorDictBase, frames: int = 0) -> dict[str, float]:
        """GAE once per batch (as CleanRL), then `loss.epochs` passes in shuffled minibatches (with
        the mirror loss once `frames`, those trained on before, reach `loss.mirror_from_frames`)."""
        compute_advantage(data, self.advantage)
        mirrors = self.mirrors if frames >= self.cfg.loss.mirror_from_frames else None
        update = self._update_bfc if self.step is not None else self._update_torchrl
        metrics = update(data, mirrors)
        metrics.setdefault("loss/clip_fraction", 0.0)  # the KL-penalty loss has no clipping
        if isinstance(self.loss_module, KLPENPPOLoss):
            metrics["loss/kl_beta"] = float(self.loss_module.beta)
        return metrics

    def _minibatches(self, n: int):
        size = minibatch_size(self.cfg)
        for _ in range(self.cfg.loss.epochs):
            perm = torch.randperm(n)
            for start in range(0, n, size):
                yield perm[start : start + size]

    def _update_bfc(self, data: TensorDictBase, mirrors) -> dict[str, float]:
        """Each minibatch one gather from a (frames, columns) table of plain tensors, one PPOStep."""
        step = self.step
        columns = [
            step.observe(data.get(keys.OBSERVATION)),
            data.get(keys.ACTION),
            data.get(self.loss_module.tensor_keys.sample_log_prob).unsqueeze(-1),
            data.get("advantage"),
            data.get("value_target"),
        ]
        if step.clip_value is not None:  # the collected value, which clip_value keeps the new one near
            columns.append(data.get("state_value"))
        columns = [c.reshape(data.numel(), -1) for c in columns]
        views, kept = 0, None
        if mirrors is not None:  # the observations in each mirror (or each row's), side by side
            obs, rows = data.get(keys.OBSERVATION).reshape(data.numel(), -1), torch.arange(data.numel())
            seen = step.observe(mirrors.observations(obs, mirrors.reflection(rows)))
            views, kept = seen.shape[0], mirrors.kept(obs)
            columns.append(seen.transpose(0, 1).flatten(1))
        widths = [c.shape[-1] for c in columns]
        table = torch.cat(columns, -1)
        total, count = torch.zeros(len(PPOStep.METRICS)), 0
        for index in self._minibatches(table.shape[0]):
            obs, action, log_prob, adv, target, *rest = table[index].split(widths, -1)
            mirrored = reflection = None
            if views:
                mirrored = rest.pop().view(len(index), views, -1).transpose(0, 1)
                reflection = mirrors.reflection(index)
            args = (obs, action, log_prob.squeeze(-1), adv, target, *rest)
            rows_kept = None if kept is None else kept[index]
            total += step(*args, mirrored=mirrored, reflection=reflection, kept=rows_kept)
            count += 1
        metrics = {LOSS_TAGS[key]: float(value) / count for key, value in zip(PPOStep.METRICS, total, strict=True)}
        if not views:
            del metrics["loss/mirror"]
        return metrics

    def _update_torchrl(self, data: TensorDictBase, mirrors) -> dict[str, float]:
        """TensorDict minibatches through TorchRL's loss module, autograd, torch's clipping and Adam."""
        params, optimizer = list(self.loss_module.parameters()), self.optimizer
        flat = data.select(*_LOSS_KEYS, strict=False).reshape(-1)
        sums: dict[str, torch.Tensor] = {}
        count = 0
        for index in self._minibatches(flat.shape[0]):
            batch = flat[index]
            out = self.loss_module(batch)
            total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", 0.0)
            if mirrors is not None:
                obs, reflection = batch.get(keys.OBSERVATION), mirrors.reflection(index)
                seen = mirrors.observations(obs, reflection)
                mirrored = self.actor_net.mean(seen.flatten(0, 1)).view(seen.shape[:2] + (-1,))
                out["mirror"], _ = mirrors.loss(self.actor_net.mean(obs), mirrored, reflection, mirrors.kept(obs))
                total = total + out["mirror"]
            optimizer.zero_grad(set_to_none=True)
            total.backward()
            torch.nn.utils.clip_grad_norm_(params, self.cfg.optim.max_grad_norm)
            optimizer.step()
            for key, tag in LOSS_TAGS.items():
                if key in out.keys():
                    value = out[key].detach().mean()
                    sums[tag] = sums[tag] + value if tag in sums else value
            count += 1
        return {tag: float(value) / count for tag, value in sums.items()}

    def state_dict(self) -> dict:
        return {"optimizer": self.optimizer.state_dict(), "loss": self.loss_module.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        if self.step is not None:
            self.step.load_state_dict(state["optimizer"])
        else:
            self.optimizer.load_state_dict(state["optimizer"])
        self.loss_module.load_state_dict(state["loss"], strict=False)
