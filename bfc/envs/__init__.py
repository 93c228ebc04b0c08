"""The MuJoCo quadrotor (an airframe as data, the Hummingbird by default) as a batched TorchRL env.

The parameter dataclasses import nothing heavy; `QuadrotorEnv` (torch, TorchRL, MuJoCo) is
imported on first use, so that a config can be checked before those load (bfc.config).
"""

from bfc.envs.params import (
    GOAL,
    REFERENCE_PHYSICS_DT,
    AirframeParams,
    EnvParams,
    JDParams,
    RandomizeParams,
    RewardParams,
    StartParams,
    TerminationParams,
)

__all__ = [
    "GOAL",
    "REFERENCE_PHYSICS_DT",
    "AirframeParams",
    "EnvParams",
    "JDParams",
    "QuadrotorEnv",
    "RandomizeParams",
    "RewardParams",
    "StartParams",
    "TerminationParams",
]


def __getattr__(name: str):
    if name == "QuadrotorEnv":
        from bfc.envs import quadrotor

        return getattr(quadrotor, name)
    raise AttributeError(f"module 'bfc.envs' has no attribute {name!r}")
