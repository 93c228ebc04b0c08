"""Models, PPO loss and update, the training loop, checkpoints and resume."""

from bfc.training.trainer import train

__all__ = ["train"]
