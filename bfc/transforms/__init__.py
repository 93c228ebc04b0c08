"""Composable TorchRL transforms: odometry noise, the BFC start samplers (JD, CSS), TDTS, and
the policy-side observation and action maps."""

from bfc.transforms.action import MotorSpeedAction
from bfc.transforms.css import ControlledStartingState
from bfc.transforms.jd import JumpingDistribution
from bfc.transforms.noise import GaussianOdometryNoise, OUOdometryNoise, element_mask
from bfc.transforms.observation import PolicyObservation
from bfc.transforms.starts import GivenStarts
from bfc.transforms.tdts import TimeDependentTerminalState

__all__ = [
    "ControlledStartingState",
    "GaussianOdometryNoise",
    "JumpingDistribution",
    "MotorSpeedAction",
    "OUOdometryNoise",
    "PolicyObservation",
    "GivenStarts",
    "TimeDependentTerminalState",
    "element_mask",
]
