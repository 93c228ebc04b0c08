"""The baselines' gains per built-in airframe: factors on top of each controller's own scaling to
the airframe, chosen on the validation starts by `python bench/tune_baselines.py --airframe NAME`
(a grid over the gain groups, scored on the rows of suite=robust and suite=hardware;
docs/controllers.md has the grid, the scores and why). On the Hummingbird the factors act
on the published RotorS and Kamel sets (`build(..., tuned=False)` flies those as published); an
airframe not listed (a user's own) flies the factors 1.

`CONTROLLERS` (bfc.controllers) builds every baseline through `build`, so `controller=lee` on the
Crazyflie flies its tuned gains wherever a controller is named: evaluate.py, `fly`, RotorPy.
"""

from __future__ import annotations

from bfc.controllers.base import Controller
from bfc.controllers.lee import LeeController, lee_with_integral
from bfc.controllers.mpc import LinearMPC
from bfc.envs.params import AirframeParams

TUNED: dict[str, dict[str, dict[str, float]]] = {
    # bench/tune_baselines.py --airframe hummingbird, 30 validation starts per row, each scored on the
    # 20 rows of both suites (lee_i: the published set scored best)
    "hummingbird": {
        "lee": {"position": 2.0, "velocity": 2.0},
        "lee_i": {},
        "mpc": {"angular_rate": 0.5},
    },
    # bench/tune_baselines.py --airframe crazyflie, 30 validation starts per row, each scored on the
    # 20 rows of both suites
    "crazyflie": {
        "lee": {"position": 0.5, "attitude": 0.5},
        "lee_i": {"velocity": 2.0, "attitude": 0.5},
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


def build(name: str, airframe: AirframeParams, dt: float, tuned: bool = True, config=None) -> Controller:
    """Baseline `name` for `airframe` at period `dt`, with the airframe's tuned gains (tuned=False:
    without them, as the tuning grid starts). `config`: the maker's own settings where it takes
    them (lee: LeeGains, mpc: MPCParams, e.g. a fixed heading), tuned the same way."""
    controller = MAKERS[name](airframe, dt) if config is None else MAKERS[name](airframe, dt, config)
    return controller.scale_gains(**tuned_factors(name, airframe)) if tuned else controller
