"""Classical baselines that speak the policy's action interface (odometry + goal in, rad/s out).

`CONTROLLERS` maps the names `evaluate.py controller=...` and `bfc.evaluation.fly(...)` accept to
factories `(airframe, dt) -> Controller`.
"""

from bfc.controllers.base import Controller, Odometry
from bfc.controllers.lee import LeeController, LeeGains, lee_with_integral
from bfc.controllers.mixer import Mixer, allocation_matrix
from bfc.controllers.mpc import LinearMPC, MPCParams

CONTROLLERS = {"lee": LeeController, "lee_i": lee_with_integral, "mpc": LinearMPC}

__all__ = [
    "CONTROLLERS",
    "Controller",
    "LeeController",
    "LeeGains",
    "LinearMPC",
    "MPCParams",
    "Mixer",
    "Odometry",
    "allocation_matrix",
    "lee_with_integral",
]
