"""The MuJoCo Hummingbird as a batched TorchRL env."""

from bfc.envs.params import AirframeParams
from bfc.envs.quadrotor import QuadrotorEnv, RandomizeParams, RewardParams, StartParams, TerminationParams

__all__ = ["AirframeParams", "QuadrotorEnv", "RandomizeParams", "RewardParams", "StartParams", "TerminationParams"]
