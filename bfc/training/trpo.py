"""TRPO (Schulman et al. 2015), which the paper compares with PPO (figs. 5-7). TorchRL has no TRPO
loss, so the step is built here on its pieces: the same Gaussian actor and critic as PPO, TorchRL's
GAE (eq. 15), and a natural-gradient step on the surrogate (conjugate gradient on Fisher-vector
products of the mean KL) scaled to the KL bound `algo.trpo.max_kl` and checked by a backtracking line
search: a step is taken only if the surrogate improves and the measured KL stays within the bound.
The critic is fitted with Adam (`algo.trpo.critic_epochs` passes of `critic_minibatches`
minibatches, lr `optim.lr`), as in the original. It reads the `algo.trpo` section (and `optim`).
"""

from __future__ import annotations

import math

import torch

from bfc import keys
from bfc.agent import GaussianActor, gaussian_net
from bfc.training.advantage import compute_advantage, make_gae


def _flat(tensors) -> torch.Tensor:
    return torch.cat([t.reshape(-1) for t in tensors])


def conjugate_gradient(fvp, b: torch.Tensor, iterations: int, tolerance: float = 1e-10) -> torch.Tensor:
    """Approximately solve F x = b given x -> F x (F symmetric positive definite)."""
    x = torch.zeros_like(b)
    r, p = b.clone(), b.clone()
    rr = r @ r
    for _ in range(iterations):
        fp = fvp(p)
        alpha = rr / (p @ fp)
        x += alpha * p
        r -= alpha * fp
        new_rr = r @ r
        if new_rr < tolerance:
            break
        p = r + (new_rr / rr) * p
        rr = new_rr
    return x


class TRPO:
    """The TRPO learner: `update(data, frames)` takes one natural-gradient policy step per batch and fits
    the critic. Same interface as `bfc.training.ppo.PPO`."""

    def __init__(self, cfg, actor, critic):
        self.cfg, self.algo = cfg, cfg.algo.trpo
        self.net = gaussian_net(actor)
        self.critic = critic
        self.params = [p for p in self.net.parameters() if p.requires_grad]
        self.advantage = make_gae(self.algo.gamma, self.algo.lmbda, critic)
        self.optimizer = torch.optim.Adam(critic.parameters(), lr=cfg.optim.lr, eps=cfg.optim.adam_eps)
        self.optimizers = [self.optimizer]
        self.last_kl = 0.0

    def _set_params(self, flat: torch.Tensor) -> None:
        i = 0
        for p in self.params:
            n = p.numel()
            p.data.copy_(flat[i : i + n].view_as(p))
            i += n

    def policy_step(self, obs, action, old_log_prob, adv) -> dict[str, float]:
        """One KL-bounded natural-gradient step on the surrogate E[pi/pi_old A]."""
        a = self.algo
        with torch.no_grad():
            old_loc, old_scale = self.net(obs)

        def surrogate():
            loc, scale = self.net(obs)
            ratio = (GaussianActor.log_prob(action, loc, scale) - old_log_prob).exp()
            return (ratio * adv).mean()

        def mean_kl():
            loc, scale = self.net(obs)
            return GaussianActor.kl(old_loc, old_scale, loc, scale).mean()

        def fvp(v):
            grads = torch.autograd.grad(mean_kl(), self.params, create_graph=True)
            return _flat(torch.autograd.grad(_flat(grads) @ v, self.params)) + a.damping * v

        before = surrogate()
        g = _flat(torch.autograd.grad(before, self.params))
        direction = conjugate_gradient(fvp, g, a.cg_iterations)
        shs = 0.5 * direction @ fvp(direction)
        if not bool(torch.isfinite(shs)) or shs <= 0:
            return {"loss/objective": -float(before), "loss/approx_kl": 0.0, "loss/step_fraction": 0.0}
        step = direction * torch.sqrt(a.max_kl / shs)
        start = _flat(p.data for p in self.params)
        accepted, kl, fraction = False, 0.0, 0.0
        with torch.no_grad():
            for k in range(a.line_search_steps):
                fraction = 0.5**k
                self._set_params(start + fraction * step)
                after, kl = surrogate(), float(mean_kl())
                if math.isfinite(kl) and kl <= a.max_kl and after > before:
                    accepted = True
                    break
            if not accepted:
                self._set_params(start)
                after, kl, fraction = before, 0.0, 0.0
        self.last_kl = kl
        return {"loss/objective": -float(after), "loss/approx_kl": kl, "loss/step_fraction": fraction}

    def update(self, data, frames: int = 0) -> dict[str, float]:
        compute_advantage(data, self.advantage)
        flat = data.reshape(-1)
        obs, action = flat.get(keys.OBSERVATION), flat.get(keys.ACTION)
        old_log_prob = flat.get("action_log_prob")
        adv = flat.get("advantage").squeeze(-1)
        adv = (adv - adv.mean()) / adv.std().clamp_min(1e-8)
        metrics = self.policy_step(obs, action, old_log_prob, adv)
        target = flat.get("value_target")
        size = max(1, obs.shape[0] // int(self.algo.critic_minibatches))
        params, critic_losses = list(self.critic.parameters()), []
        for _ in range(self.algo.critic_epochs):
            perm = torch.randperm(obs.shape[0])
            for s in range(0, obs.shape[0], size):
                idx = perm[s : s + size]
                loss = (self.critic.module(obs[idx]) - target[idx]).square().mean()
                self.optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(params, self.cfg.optim.max_grad_norm)
                self.optimizer.step()
                critic_losses.append(float(loss.detach()))
        metrics["loss/critic"] = sum(critic_losses) / len(critic_losses)
        with torch.no_grad():
            metrics["loss/entropy"] = float(GaussianActor.entropy(self.net(obs[:1])[1]).mean())
        return metrics

    def state_dict(self) -> dict:
        return {"optimizer": self.optimizer.state_dict()}

    def load_state_dict(self, state: dict) -> None:
        self.optimizer.load_state_dict(state["optimizer"])
