"""The MuJoCo Hummingbird as a batched TorchRL env."""

from bfc.envs.params import AirframeParams
from bfc.envs.quadrotor import (
    REFERENCE_PHYSICS_DT,
    QuadrotorEnv,
    RandomizeParams,
    RewardParams,
    StartParams,
    TerminationParams,
)

__all__ = [
    "REFERENCE_PHYSICS_DT",
    "AirframeParams",
    "QuadrotorEnv",
    "RandomizeParams",
    "RewardParams",
    "StartParams",
    "TerminationParams",
]
