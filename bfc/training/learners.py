"""The learner registry: `algo.name` -> the class that trains the policy.

Every learner has the same interface: `update(data, frames) -> metrics` (`frames`: those trained
on before this batch, which a schedule reads), `optimizers` (the learning-rate
anneal scales them all), `state_dict()` / `load_state_dict()` (its part of a checkpoint), and
is built from the actor, the critic and its own config section (PPO `loss`, TRPO `algo.trpo`,
DDPG `algo.ddpg`; all of them `optim`).
"""

from __future__ import annotations

from bfc.config import ALGORITHMS


def make_learner(cfg, actor, critic):
    """The learner `algo.name` names (ppo, trpo, ddpg)."""
    name = cfg.algo.name
    if name == "ppo":
        from bfc.training.ppo import PPO

        return PPO(cfg, actor, critic)
    if name == "trpo":
        from bfc.training.trpo import TRPO

        return TRPO(cfg, actor, critic)
    if name == "ddpg":
        from bfc.training.ddpg import DDPG

        return DDPG(cfg, actor, critic)
    raise ValueError(f"algo.name must be one of {', '.join(ALGORITHMS)}, got {name!r}")


def learner_gamma(cfg) -> float:
    """The discount the learner `algo.name` uses (PPO `loss.gamma`, TRPO and DDPG their own)."""
    name = cfg.algo.name
    return float(cfg.loss.gamma if name == "ppo" else cfg.algo[name].gamma)
