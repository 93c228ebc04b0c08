"""Classical baselines that speak the policy's action interface (odometry + goal in, rad/s out).

`CONTROLLERS` maps the names `evaluate.py controller=...` and `bfc.evaluation.fly(...)` accept to
factories `(airframe, dt) -> Controller`, each with the airframe's tuned gains (bfc.controllers.tuned).
"""

from functools import partial

from bfc.controllers.base import Controller, Odometry
from bfc.controllers.lee import LeeController, LeeGains, lee_with_integral
from bfc.controllers.mixer import Mixer, allocation_matrix
from bfc.controllers.mpc import LinearMPC, MPCParams
from bfc.controllers.tuned import MAKERS, TUNED, build, tuned_factors

CONTROLLERS = {name: partial(build, name) for name in MAKERS}

__all__ = [
    "CONTROLLERS",
    "Controller",
    "LeeController",
    "LeeGains",
    "LinearMPC",
    "MPCParams",
    "Mixer",
    "Odometry",
    "TUNED",
    "allocation_matrix",
    "build",
    "lee_with_integral",
    "tuned_factors",
]
