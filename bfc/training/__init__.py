"""Models, PPO loss and update, the training runner, checkpoints and resume."""

from bfc.training.runner import Runner, train

__all__ = ["Runner", "train"]
