"""PPO's minibatch step with its gradients written out: the forward of the actor's and the
critic's MLPs, ClipPPOLoss's clipped surrogate, critic and entropy terms, their backward, the
gradient clipping and Adam, as plain tensor operations over one flat parameter buffer.

Why: at bfc's sizes (two hidden layers of 128-256, minibatches of 256-512) autograd's graph, the
per-parameter optimizer and torch's CPU tanh cost half as much again as the matrix products
(bench/update_time.py): the step here runs the products (now about 70% of it) and a few dozen
elementwise kernels. It gives ClipPPOLoss's gradients on the same minibatch to float rounding
(tests/training/test_ppo_step.py; not bit for bit: the surrogate's gradient is formed in one
expression where autograd chains five, the entropy's is added in another order, and tanh is
2 sigmoid(2z) - 1).

It knows the networks bfc builds (`GaussianActor` over TorchRL's MLP, the critic's MLP, the
shared observation statistics); `loss.implementation=torchrl` trains any other through
TorchRL's module.
"""

from __future__ import annotations

import torch
from torch import nn
from torchrl.modules import MLP
from torchrl.objectives.utils import distance_loss

from bfc.agent import GaussianActor, gaussian_net
from bfc.agent.normalization import Normalized

# a hidden layer, activation(x W^T + b), in place on the product; tanh as 2 sigmoid(2z) - 1 (the
# 2z from the product itself): torch's CPU tanh costs six of its sigmoids
_HIDDEN = {
    nn.ReLU: lambda x, w, b: torch.addmm(b, x, w.t()).relu_(),
    nn.Tanh: lambda x, w, b: torch.addmm(b, x, w.t(), beta=2, alpha=2).sigmoid_().mul_(2).sub_(1),
    nn.ELU: lambda x, w, b: nn.functional.elu(torch.addmm(b, x, w.t()), inplace=True),
}
# d activation / d input from the activation's output (ELU's alpha 1: exp(z) = output + 1)
_BACKWARD = {
    nn.ReLU: lambda grad, out: torch.ops.aten.threshold_backward(grad, out, 0),
    nn.Tanh: lambda grad, out: torch.ops.aten.tanh_backward(grad, out),
    nn.ELU: lambda grad, out: torch.ops.aten.elu_backward(grad, 1.0, 1.0, 1.0, True, out),
}


class _Dense:
    """A TorchRL MLP (Linear, activation, ..., Linear) run by hand: `forward` keeps each layer's
    input, `backward` writes every weight's and bias's gradient into its slot of the flat buffer."""

    def __init__(self, mlp: nn.Module, grad_of):
        linears = [m for m in mlp if isinstance(m, nn.Linear)]
        activations = {type(m) for m in mlp if not isinstance(m, nn.Linear)}
        if not isinstance(mlp, MLP) or len(activations) != 1 or next(iter(activations)) not in _BACKWARD:
            raise ValueError("bfc's PPO step runs TorchRL MLPs with tanh, relu or elu; use loss.implementation=torchrl")
        (activation,) = activations
        self.hidden, self.backward_of = _HIDDEN[activation], _BACKWARD[activation]
        self.layers = [(m.weight, m.bias, grad_of(m.weight), grad_of(m.bias)) for m in linears]

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, list[torch.Tensor]]:
        inputs = []
        for weight, bias, _, _ in self.layers[:-1]:
            inputs.append(x)
            x = self.hidden(x, weight, bias)
        inputs.append(x)
        weight, bias, _, _ = self.layers[-1]
        return torch.addmm(bias, x, weight.t()), inputs

    def backward(self, grad: torch.Tensor, inputs: list[torch.Tensor]) -> None:
        for i in range(len(self.layers) - 1, -1, -1):
            weight, _, grad_weight, grad_bias = self.layers[i]
            torch.mm(grad.t(), inputs[i], out=grad_weight)
            torch.sum(grad, 0, out=grad_bias)
            if i:
                grad = self.backward_of(grad.mm(weight), inputs[i])


def _distance_grad(kind: str, pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """d distance_loss(target, pred, kind) / d pred: TorchRL's l2, l1 and smooth_l1 (beta 1),
    whose values the step takes from `distance_loss` itself."""
    diff = pred - target
    if kind == "l2":
        return 2 * diff
    if kind == "l1":
        return diff.sign()
    return diff.clamp(-1.0, 1.0)


class PPOStep:
    """One minibatch step: loss, gradients, clipping, Adam. Built from the ClipPPOLoss it stands
    for (its epsilon, critic loss and coefficient, value clipping and entropy coefficient are read
    from it; an option it does not implement is refused) and the actor and critic it trains.

    The parameters become views of one flat buffer (`flat`, the only parameter its Adam sees) and
    their gradients views of another, so the clipping is one norm and Adam one fused kernel.
    """

    METRICS = ("loss_objective", "loss_critic", "entropy", "kl_approx", "clip_fraction", "mirror")

    def __init__(self, loss, actor, critic, lr: float, adam_eps: float, max_grad_norm: float, mirrors=None):
        unsupported = {
            "separate_losses": loss.separate_losses or None,
            "advantage_norm": getattr(loss, "advantage_norm", None),
            "max_importance_ratio": getattr(loss, "max_importance_ratio", None),
        }
        used = [name for name, value in unsupported.items() if value is not None]
        if used or not loss.normalize_advantage:
            what = ", ".join(used) or "normalize_advantage=False"
            raise ValueError(f"bfc's PPO step does not implement ClipPPOLoss's {what}; use loss.implementation=torchrl")
        net = gaussian_net(actor)
        value = critic.module
        if net is None:
            raise ValueError("bfc's PPO step trains bfc's GaussianActor; use loss.implementation=torchrl")
        self.obs_norm = net.obs_norm
        if isinstance(value, Normalized):
            if value.obs_norm is not net.obs_norm:
                raise ValueError("bfc's PPO step needs the critic to share the actor's observation statistics")
            value = value.module
        elif net.obs_norm is not None:
            raise ValueError("bfc's PPO step needs the critic on the actor's normalised observation")
        epsilon = loss.clip_epsilon.detach()  # ClipPPOLoss's bounds on log(ratio), in its float32
        self.low, self.high = float((-epsilon).log1p()), float(epsilon.log1p())
        self.critic_coeff = float(loss.critic_coeff)
        self.clip_value = float(loss.clip_value) if loss.clip_value is not None else None
        self.critic_loss = loss.loss_critic_type
        self.entropy_coeff = float(loss.entropy_coeff)
        self.eps = torch.finfo(torch.float).resolution  # torchrl's advantage standardisation
        self.squash, self.max_log_std = net.squash, net.max_log_std
        self.max_grad_norm = float(max_grad_norm)
        self.mirrors = mirrors  # bfc.training.mirror.Mirrors, or None

        params = list(loss.parameters())
        mine = [*net.mlp.parameters(), net.log_std, *value.parameters()]
        if {id(p) for p in params} != {id(p) for p in mine}:
            raise ValueError("bfc's PPO step found parameters it does not train; use loss.implementation=torchrl")
        self.params = params  # the order of the flat buffer: the loss module's, as torch's Adam saw them
        with torch.no_grad():
            self.flat = nn.Parameter(torch.cat([p.detach().reshape(-1) for p in params]))
        self.flat.grad = torch.zeros_like(self.flat)
        slots, start = {}, 0
        for p in params:
            view = slice(start, start + p.numel())
            p.data = self.flat.data[view].view_as(p)
            slots[id(p)] = self.flat.grad[view].view_as(p)
            start += p.numel()
        self.log_std = net.log_std
        self.grad_log_std = slots[id(net.log_std)]
        self.actor = _Dense(net.mlp, lambda p: slots[id(p)])
        self.critic = _Dense(value, lambda p: slots[id(p)])
        self.optimizer = torch.optim.Adam([self.flat], lr=lr, eps=adam_eps, fused=True)

    def observe(self, obs: torch.Tensor) -> torch.Tensor:
        """What both networks read: the observation, through the statistics when it has them
        (constant over an update: the table is put through them once)."""
        if self.obs_norm is None:
            return obs
        with torch.no_grad():
            return self.obs_norm(obs)

    @torch.no_grad()
    def __call__(
        self,
        obs,
        action,
        old_log_prob,
        advantage,
        value_target,
        old_value=None,
        mirrored=None,
        reflection=None,
        kept=None,
    ):
        """One step on a minibatch of (n, .) columns (`obs` already through `observe`; `mirrored`,
        with mirrors, (m, n, size): the observations in each mirror, through `observe` too, or
        (1, n, size) with `reflection` (n,), the one each row went through; `kept` (n,): the rows
        the mirror loss holds, Mirrors.kept); returns the METRICS as one tensor."""
        n = obs.shape[0]
        advantage = ((advantage - advantage.mean()) / advantage.std().clamp_min(self.eps)).squeeze(-1)
        # the actor: log N(action; loc, scale) and the clipped surrogate (and, with mirrors, its
        # means on the mirrored observations in the same pass)
        rows = obs if mirrored is None else torch.cat((obs, mirrored.flatten(0, 1)))
        loc_all, actor_inputs = self.actor.forward(rows)
        if self.squash:
            loc_all = loc_all.tanh()
        loc = loc_all[:n]
        log_std = self.log_std if self.max_log_std is None else self.log_std.clamp(max=self.max_log_std)
        scale = log_std.exp()
        log_prob = GaussianActor.log_prob(action, loc, scale)
        z = (action - loc) / scale  # d log_prob / d loc = z / scale; d log_prob / d log_std = z^2 - 1
        log_weight = log_prob - old_log_prob
        clipped = log_weight.clamp(self.low, self.high)
        ratio_gain = log_weight.exp() * advantage
        clipped_gain = clipped.exp() * advantage
        unclipped = ratio_gain <= clipped_gain  # where the minimum is the unclipped term
        # d loss / d log_prob = -advantage * ratio / n where the unclipped term is taken, else 0
        grad_log_prob = torch.where(unclipped, ratio_gain, 0.0).mul_(-1.0 / n).unsqueeze(-1)
        grad_loc = grad_log_prob * z / scale
        if self.squash:
            grad_loc = grad_loc * (1 - loc.square())
        grad_log_std = (grad_log_prob * (z.square() - 1)).sum(0) - self.entropy_coeff
        if self.max_log_std is not None:
            grad_log_std = grad_log_std * (self.log_std <= self.max_log_std)
        self.grad_log_std.copy_(grad_log_std)
        mirror = torch.zeros(())
        if mirrored is not None:
            mirrored_loc = loc_all[n:].view(mirrored.shape[0], n, -1)
            mirror, grad_mirrored = self.mirrors.loss(loc, mirrored_loc, reflection, kept)
            grad_mirrored = grad_mirrored.flatten(0, 1)
            if self.squash:
                grad_mirrored = grad_mirrored * (1 - loc_all[n:].square())
            grad_loc = torch.cat((grad_loc, grad_mirrored))
        self.actor.backward(grad_loc, actor_inputs)
        # the critic
        value, critic_inputs = self.critic.forward(obs)
        critic = distance_loss(value_target, value, self.critic_loss)
        grad_value = _distance_grad(self.critic_loss, value, value_target)
        if self.clip_value is not None:  # ClipPPOLoss's clip_value: the more pessimistic of the two
            moved = value - old_value
            near = old_value + moved.clamp(-self.clip_value, self.clip_value)
            critic_near = distance_loss(value_target, near, self.critic_loss)
            grad_near = _distance_grad(self.critic_loss, near, value_target) * (moved.abs() <= self.clip_value)
            take_near = critic_near > critic
            critic = torch.maximum(critic, critic_near)
            grad_value = torch.where(take_near, grad_near, grad_value)
        self.critic.backward(grad_value.mul_(self.critic_coeff / n), critic_inputs)
        # clip the whole gradient's norm, then Adam
        grad = self.flat.grad
        norm = grad.norm()
        grad.mul_((self.max_grad_norm / (norm + 1e-6)).clamp_(max=1.0))
        self.optimizer.step()
        entropy = GaussianActor.entropy(scale)
        return torch.stack(
            (
                -torch.minimum(ratio_gain, clipped_gain).mean(),
                critic.mean() * self.critic_coeff,
                entropy,
                -log_weight.mean(),
                (clipped != log_weight).float().mean(),
                mirror,
            )
        )

    def state_dict(self) -> dict:
        return self.optimizer.state_dict()

    def load_state_dict(self, state: dict) -> None:
        """Adam's state over the flat buffer, or (a checkpoint written before this step) torch's
        Adam over the loss module's parameters one by one, concatenated in their order."""
        ids = state["param_groups"][0]["params"]
        if len(ids) == len(self.params) and len(self.params) > 1:
            per = [state["state"][i] for i in ids]
            flat = {
                "step": per[0]["step"],
                "exp_avg": torch.cat([s["exp_avg"].reshape(-1) for s in per]),
                "exp_avg_sq": torch.cat([s["exp_avg_sq"].reshape(-1) for s in per]),
            }
            group = {**state["param_groups"][0], "params": [0]}
            state = {"state": {0: flat}, "param_groups": [group]}
        self.optimizer.load_state_dict(state)
