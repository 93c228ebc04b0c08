"""What every classical controller shares: the action interface of a policy.

A controller is a TensorDictModule that reads `"odometry"` (what the sensors report, so odometry
noise reaches it as it reaches a policy) and `"goal"`, and writes `"action"` (motor speeds, rad/s).
Per-env state (integrators, held commands) lives in tensors sized on the first call; `reset()`
clears it between flights.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from bfc import keys
from bfc.controllers.mixer import Mixer
from bfc.envs.params import AirframeParams
from bfc.envs.rotations import euler_to_quat, quat_to_matrix


@dataclass
class Odometry:
    """The 18 odometry numbers split into named float64 parts, plus the rotation matrix."""

    position: torch.Tensor  # (n, 3) world
    velocity: torch.Tensor  # (n, 3) world
    acceleration: torch.Tensor  # (n, 3) world
    rpy: torch.Tensor  # (n, 3) roll, pitch, yaw (ZYX)
    angular_velocity: torch.Tensor  # (n, 3) body
    rotation: torch.Tensor  # (n, 3, 3) body to world

    @classmethod
    def parse(cls, odometry: torch.Tensor) -> Odometry:
        if odometry.ndim != 2 or odometry.shape[-1] != 18:
            raise ValueError(f"odometry must have shape (n, 18), got {tuple(odometry.shape)}")
        o = odometry.to(torch.float64)
        rpy = o[:, keys.ODOM_ATTITUDE]
        return cls(
            position=o[:, keys.ODOM_POSITION],
            velocity=o[:, keys.ODOM_LINEAR_VELOCITY],
            acceleration=o[:, keys.ODOM_LINEAR_ACCELERATION],
            rpy=rpy,
            angular_velocity=o[:, keys.ODOM_ANGULAR_VELOCITY],
            rotation=quat_to_matrix(euler_to_quat(rpy)),
        )


class Controller(TensorDictModuleBase):
    """Base class: subclasses implement `command(odometry, goal) -> motor speeds (n, 4)`."""

    in_keys = [keys.ODOMETRY, keys.GOAL]
    out_keys = [keys.ACTION]

    def __init__(self, airframe: AirframeParams, dt: float):
        super().__init__()
        if dt <= 0:
            raise ValueError(f"dt (the control period) must be > 0, got {dt}")
        self.airframe, self.dt = airframe, float(dt)
        self.mixer = Mixer(airframe)
        self.mass, self.gravity = airframe.total_mass, airframe.gravity
        self.inertia = torch.tensor(airframe.rigid_inertia, dtype=torch.float64)

    def reset(self) -> None:
        """Forget per-flight state (subclasses with state extend this)."""

    def begin_flight(self) -> None:
        """Called by `run_flights` before each flight."""
        self.reset()

    def forward(self, td: TensorDictBase) -> TensorDictBase:
        odometry = td.get(keys.ODOMETRY)
        goal = td.get(keys.GOAL).to(torch.float64)
        speeds = self.command(Odometry.parse(odometry), goal)
        td.set(keys.ACTION, speeds.to(odometry.dtype))
        return td

    def command(self, odo: Odometry, goal: torch.Tensor) -> torch.Tensor:
        raise NotImplementedError

    def gyroscopic(self, w: torch.Tensor) -> torch.Tensor:
        """w x (J w): the torque that Euler's equations need to hold the body rate (added by both
        controllers to the torque their feedback asks for)."""
        return torch.cross(w, self.inertia * w, dim=-1)
