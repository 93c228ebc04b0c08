"""The baselines' gains per built-in airframe: factors on top of each controller's own scaling to
the airframe, chosen on the validation starts by `python bench/tune_baselines.py --airframe NAME`
(a grid over the gain groups, scored on the rows of suite=robust and suite=hardware, or as an entry
says; docs/controllers.md has the grid, the scores and why). An airframe not listed (the
Hummingbird, whose published RotorS and Kamel sets these are, or a user's own) flies the factors 1.

`CONTROLLERS` (bfc.controllers) builds every baseline through `build`, so `controller=lee` on the
Crazyflie flies its tuned gains wherever a controller is named: evaluate.py, `fly`, RotorPy.
"""

from __future__ import annotations

from bfc.controllers.base import Controller
from bfc.controllers.lee import LeeController, lee_with_integral
from bfc.controllers.mpc import LinearMPC
from bfc.envs.params import AirframeParams

TUNED: dict[str, dict[str, dict[str, float]]] = {
    # bench/tune_baselines.py --airframe crazyflie, 30 validation starts per row: the MPC scored on the
    # 20 rows of both suites, Lee and lee_i on the 12 robust rows (--suites robust)
    "crazyflie": {
        "lee": {"position": 0.5, "angular_rate": 2.0},
        "lee_i": {"velocity": 2.0, "angular_rate": 2.0},
        "mpc": {"attitude": 0.5, "angular_rate": 0.5},
    },
    # bench/tune_baselines.py --airframe x500, 30 validation starts per row, each scored on the 20
    # rows of both suites
    "x500": {
        "lee": {"position": 0.5, "velocity": 0.5},
        "lee_i": {"velocity": 2.0},
        "mpc": {"angular_rate": 0.5},
    },
}

MAKERS = {  # every baseline by name (config.CONTROLLER_NAMES checks names before torch loads)
    "lee": LeeController,
    "lee_i": lee_with_integral,
    "mpc": LinearMPC,
}


def tuned_factors(name: str, airframe: AirframeParams) -> dict[str, float]:
    """The gain factors controller `name` flies on `airframe` (empty: its own scaling alone)."""
    return dict(TUNED.get(airframe.name, {}).get(name, {}))


def build(name: str, airframe: AirframeParams, dt: float, tuned: bool = True) -> Controller:
    """Baseline `name` for `airframe` at period `dt`, with the airframe's tuned gains (tuned=False:
    without them, as the tuning grid starts)."""
    controller = MAKERS[name](airframe, dt)
    return controller.scale_gains(**tuned_factors(name, airframe)) if tuned else controller
