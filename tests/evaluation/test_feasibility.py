"""The crash search: a plan it calls saving flies uncrashed when replayed, and a start no command
can save is reported unsaved, with how hard it looked."""

import dataclasses

import pytest
import torch
from tensordict.nn import TensorDictModule

from bfc import keys
from bfc.config import airframe_params
from bfc.evaluation import fly
from bfc.evaluation.feasibility import SearchBudget, _OpenLoop, search_start

CF = airframe_params("crazyflie")
SMALL = SearchBudget(population=64, iterations=6, elite=8, knot_seconds=0.1, horizon_seconds=2.0)


def _start(z, vz=0.0, roll=0.0):
    s = torch.zeros(12)
    s[2], s[3], s[8] = z, roll, vz
    return s


def test_a_level_start_high_up_is_saved_and_its_plan_flies_uncrashed():
    budget = dataclasses.replace(SMALL, population=200)
    r = search_start(_start(2.0, roll=0.3), CF, None, 50.0, budget)
    assert r.saved and r.first_crash_s is None
    assert r.rollouts <= budget.population * budget.iterations
    assert r.plan.shape == (20, 4)  # 2 s in 0.1 s knots
    assert CF.min_rotor_speed <= r.plan.min() and r.plan.max() <= CF.max_rotor_speed
    controller = TensorDictModule(_OpenLoop(r.plan[None], 5), [keys.ODOMETRY, keys.GOAL], [keys.ACTION])
    f = fly(controller, _start(2.0, roll=0.3)[None], seconds=2.0, control_hz=50.0, nominal=dataclasses.asdict(CF))
    assert bool(f.get("alive")[0, -1])  # replayed: uncrashed, and ending as the search said, upright and slow
    q = f.get(keys.QUATERNION)[0, -1]
    assert 1 - 2 * (q[1] ** 2 + q[2] ** 2) > budget.upright_cos
    assert f.get(keys.LINEAR_VELOCITY)[0, -1].norm() < budget.slow_speed


def test_a_start_falling_fast_just_above_the_floor_is_not_saved():
    # 0.2 m up at 6 m/s down: the floor comes in 33 ms, faster than the 2 m/s a landing allows
    r = search_start(_start(0.2, vz=-6.0), CF, None, 50.0, SMALL)
    assert not r.saved
    assert r.rollouts == SMALL.population * SMALL.iterations
    assert r.first_crash_s is not None and r.first_crash_s <= 0.1


def test_slower_motors_make_a_low_tilted_start_harder():
    # the same start, the same budget: the body's own motors save it where ten-times-slower ones do not
    start = _start(0.6, roll=1.0)
    assert search_start(start, CF, None, 50.0, SMALL).saved
    slow = {"time_constant_up": CF.time_constant_up * 10, "time_constant_down": CF.time_constant_down * 10}
    assert not search_start(start, CF, slow, 50.0, SMALL).saved


@pytest.mark.parametrize("bad", [dict(elite=0), dict(elite=50, population=10), dict(knot_seconds=3.0)])
def test_a_bad_budget_is_refused(bad):
    with pytest.raises(ValueError):
        SearchBudget(**bad)
