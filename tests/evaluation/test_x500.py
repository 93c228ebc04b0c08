"""The shipped X500 policy carries its airframe and flies it, from the air and from its own floor
(its exports' parity with torch: tests/test_export.py and tests/test_export_c.py)."""

import pytest

from bfc.agent import load_policy
from bfc.config import airframe_params
from bfc.evaluation import fly, protocol_starts, success
from bfc.evaluation.suites import fly_condition, score
from tests.export_helpers import X500

X5 = airframe_params("x500")


def test_its_file_holds_the_x500_it_was_trained_on():
    spec, _ = load_policy(X500)
    assert spec.nominal_airframe == X5  # every field, the layout and spins included
    assert spec.make_action_map().hover_speed == pytest.approx(X5.hover_speed)  # 769.6 rad/s, not 457.9
    assert spec.control_hz == 100.0


def test_it_flies_the_protocol_and_takes_off_from_its_own_floor():
    flights = fly(X500, protocol_starts(20, seed=0), seconds=6.0)
    assert success(flights).all()
    ground = fly_condition(X500, "ground", 10, seconds=6.0)
    assert ground.get(("state", "position"))[:, 0, 2].min() > 0.1  # resting on its 12 cm landing gear
    assert score(ground)["success_rate"] == 1.0
