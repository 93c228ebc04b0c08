"""Composable TorchRL transforms: odometry noise, latency, the BFC start samplers (JD, CSS), TDTS,
and the policy-side observation and action maps; the pipeline that runs them as one control step."""

from bfc.transforms.action import ACTION_MAPS, MotorSpeedAction
from bfc.transforms.css import ControlledStartingState
from bfc.transforms.jd import JumpingDistribution
from bfc.transforms.latency import ActionDelay, ObservationDelay
from bfc.transforms.noise import GaussianOdometryNoise, OdometryNoise, OUOdometryNoise, element_mask
from bfc.transforms.observation import OBSERVATION_SCALES, OBSERVATIONS, PolicyObservation, observation_size
from bfc.transforms.pipeline import Pipeline, Stage, StepState
from bfc.transforms.starts import GivenStarts
from bfc.transforms.tdts import TimeDependentTerminalState

__all__ = [
    "ActionDelay",
    "ObservationDelay",
    "ACTION_MAPS",
    "OBSERVATIONS",
    "OBSERVATION_SCALES",
    "ControlledStartingState",
    "GaussianOdometryNoise",
    "JumpingDistribution",
    "MotorSpeedAction",
    "OUOdometryNoise",
    "OdometryNoise",
    "PolicyObservation",
    "GivenStarts",
    "Pipeline",
    "Stage",
    "StepState",
    "TimeDependentTerminalState",
    "element_mask",
    "observation_size",
]
