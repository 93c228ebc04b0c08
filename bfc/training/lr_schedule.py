"""The learning rate of every learner's optimizers: `optim.lr`, annealed linearly to 0 at the last
frame (`optim.anneal_lr`, CleanRL's recipe) and, with `optim.desired_kl`, scaled down whenever a
PPO update moves the policy further than that (rsl_rl's adaptive schedule, capped at `optim.lr`).

Why the KL rule: under latency PPO's updates grow to a KL of 0.2-0.5 per batch (ten times the
default's) and late in the run the policy falls apart; holding the KL near a target keeps the
step a trust region whatever the task does to the gradients (docs/training.md).

The state (the KL scale and the base rate) lives in the optimizers' param groups, which their
`state_dict` saves, so a resumed run continues the same schedule.
"""

from __future__ import annotations

KL_STEP = 1.5  # rsl_rl: the rate is divided or multiplied by 1.5 per update
MIN_SCALE = 0.01  # never below 1% of optim.lr


def set_learning_rate(optimizers, anneal: float) -> None:
    """Set each group's rate to its base rate x `anneal` (1 without annealing) x its KL scale."""
    for optimizer in optimizers:
        for group in optimizer.param_groups:
            group.setdefault("initial_lr", group["lr"])
            group["lr"] = group["initial_lr"] * anneal * group.get("kl_scale", 1.0)


def adapt_to_kl(optimizers, kl: float, desired_kl: float) -> None:
    """After an update whose mean KL was `kl`: a smaller step next time if it went beyond twice the
    target, a larger one (up to the base rate) if below half of it."""
    for optimizer in optimizers:
        for group in optimizer.param_groups:
            scale = group.get("kl_scale", 1.0)
            if kl > 2.0 * desired_kl:
                scale /= KL_STEP
            elif kl < 0.5 * desired_kl:
                scale *= KL_STEP
            group["kl_scale"] = min(1.0, max(MIN_SCALE, scale))
