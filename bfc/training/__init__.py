"""Models, PPO loss and update, the training runner, checkpoints and resume."""

from bfc.torchrl_compat import import_torchrl_without_ray

import_torchrl_without_ray()  # before the runner's imports: 0.3 s of every launch (bfc.torchrl_compat)

from bfc.training.runner import Runner, train  # noqa: E402

__all__ = ["Runner", "train"]
