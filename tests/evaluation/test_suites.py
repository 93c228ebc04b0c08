"""The robustness suites: what each start set draws, model mismatch and wind in `fly`, fair baselines."""

import math

import pytest
import torch
from tensordict.nn import TensorDictModuleBase

from bfc import keys
from bfc.config import compose
from bfc.controllers import CONTROLLERS
from bfc.envs import AirframeParams
from bfc.envs.rotations import euler_to_quat
from bfc.evaluation import TEST_SEED, VALIDATION_SEED, fly, protocol_starts, success
from bfc.evaluation.metrics import tilt_degrees
from bfc.evaluation.suites import (
    CONDITIONS,
    any_starts,
    fly_condition,
    ground_starts,
    harsh_starts,
    horizontal_wind,
    robust_table,
    score,
)

DEG = math.pi / 180


def tilt(starts):
    return tilt_degrees(euler_to_quat(starts[:, 3:6].double()))


def test_harsh_starts_tilt_move_and_spin_within_their_ranges():
    s = harsh_starts(1000, seed=0)
    assert s[:, 3:5].abs().max() <= 85 * DEG + 1e-6 and (s[:, 3:5].abs() > 75 * DEG).any()
    speed = s[:, 6:9].norm(dim=-1)
    assert speed.max() <= 1.0 + 1e-6 and speed.mean() > 0.3
    assert s[:, 9:12].abs().max() <= 2.0 and (s[:, 9:12].abs() > 1.8).any()
    assert (s[:, 2] >= 0.5).all() and (s[:, 2] <= 3.0).all()


def test_any_starts_cover_every_attitude_including_upside_down():
    s = any_starts(2000, seed=0)
    inverted = (tilt(s) > 90).float().mean().item()
    assert 0.45 < inverted < 0.55  # a uniform rotation is upside down half the time
    assert (tilt(s) > 170).any()
    assert (s[:, 2] >= 1.5).all() and (s[:, 2] <= 3.0).all() and (s[:, 6:] == 0).all()


def test_ground_starts_sit_level_on_the_floor():
    s = ground_starts(200, seed=0)
    assert torch.allclose(s[:, 2], torch.full((200,), AirframeParams().ground_height))
    assert (s[:, 3:5] == 0).all() and s[:, 5].abs().max() > 2.5 and (s[:, 6:] == 0).all()
    small = AirframeParams(hull_half_size=(0.06, 0.06, 0.015))  # each airframe rests on its own hull
    assert torch.equal(ground_starts(200, 0, small)[:, :2], s[:, :2])
    assert torch.allclose(ground_starts(200, 0, small)[:, 2], torch.full((200,), 0.015))


def test_sets_are_reproducible_and_the_selection_starts_are_not_the_test_starts():
    assert torch.equal(harsh_starts(10, 3), harsh_starts(10, 3))
    assert not torch.equal(harsh_starts(10, 3), harsh_starts(10, 4))
    assert not torch.equal(protocol_starts(100, VALIDATION_SEED), protocol_starts(100, TEST_SEED))
    assert compose().eval.validation_seed == VALIDATION_SEED  # training picks policy.pt on these
    assert compose([], config_name="evaluate").eval.seed == TEST_SEED  # the docs report these


class HoverCommand(TensorDictModuleBase):
    """Commands the nominal hover speed whatever it sees."""

    in_keys, out_keys = [keys.ODOMETRY], [keys.ACTION]

    def forward(self, td):
        return td.set(keys.ACTION, torch.full((td.shape[0], 4), AirframeParams().hover_speed))


def level(n=2, z=2.0):
    s = torch.zeros(n, 12)
    s[:, 2] = z
    return s


def test_a_heavier_body_sinks_under_the_nominal_hover_thrust():
    # motors spin up from rest in the first steps; from then on nominal hover thrust holds the
    # nominal body (no vertical acceleration) and lets one 30% heavier sink at g (1 - m / m')
    nominal = fly(HoverCommand(), level(), seconds=0.3)[keys.ODOMETRY][:, 30:, 8]
    heavy = fly(HoverCommand(), level(), seconds=0.3, airframe={"body_mass": 0.68 * 1.3})[keys.ODOMETRY][:, 30:, 8]
    m = AirframeParams().total_mass
    assert nominal.abs().max().item() < 0.05
    assert heavy.mean().item() == pytest.approx(-9.81 * (1 - m / (m + 0.3 * 0.68)), rel=0.02)


def test_a_lateral_force_accelerates_the_body_at_f_over_m():
    flights = fly(HoverCommand(), level(), seconds=0.3, external_force=(1.0, 0.0, 0.0))
    ax = flights[keys.ODOMETRY][:, 1, 6]  # world x acceleration while the body is still slow
    assert ax.mean().item() == pytest.approx(1.0 / AirframeParams().total_mass, rel=0.03)
    per_env = fly(HoverCommand(), level(), seconds=0.1, external_force=[[0.0, 2.0, 0.0], [0.0, -2.0, 0.0]])
    assert per_env[keys.POSITION][0, -1, 1] > 0.005 and per_env[keys.POSITION][1, -1, 1] < -0.005
    with pytest.raises(ValueError, match="external_force must have shape"):
        fly(HoverCommand(), level(), seconds=0.1, external_force=(1.0, 0.0))
    with pytest.raises(ValueError, match="allowed keys"):
        fly(HoverCommand(), level(), seconds=0.1, airframe={"body_mas": 1.0})


def test_mismatch_leaves_the_controllers_model_and_the_policys_maps_nominal(monkeypatch):
    seen = {}

    def spy(airframe, dt):
        seen["airframe"] = airframe
        return CONTROLLERS["lee"](airframe, dt)

    monkeypatch.setitem(CONTROLLERS, "spy", spy)
    fly("spy", level(), seconds=0.1, airframe={"body_mass": 0.884})
    assert seen["airframe"].body_mass == 0.68

    from bfc.factory import find_transform, make_env
    from bfc.transforms import MotorSpeedAction

    env = make_env(compose(["env.num_envs=2"]), airframe={"motor_constant": 0.8 * 8.54858e-06})
    assert find_transform(env, MotorSpeedAction).hover_speed == pytest.approx(AirframeParams().hover_speed)
    assert env.base_env.hover_speed > AirframeParams().hover_speed  # the flown body needs more
    env.close()


@pytest.mark.parametrize("name, reaches", [("mpc", True), ("lee_i", True), ("lee", False)])
def test_offset_free_baselines_reach_the_box_with_a_30_percent_heavier_body(name, reaches):
    starts = protocol_starts(8, seed=TEST_SEED)
    flights = fly(name, starts, seconds=10.0, airframe={"body_mass": 0.68 * 1.3})
    rate = success(flights).float().mean().item()
    if reaches:
        assert rate == 1.0, name
    else:
        assert rate == 0.0  # RotorS's Lee has no integral: it hovers below the box (a documented limit)


def test_wind_is_horizontal_with_the_given_strength_and_the_table_reads_the_scores():
    w = horizontal_wind(50, 1.0, seed=0)
    assert torch.allclose(w.norm(dim=-1), torch.ones(50, dtype=w.dtype)) and (w[:, 2] == 0).all()
    flights = fly("lee", protocol_starts(4), seconds=6.0)
    s = score(flights)
    assert s["success_rate"] == 1.0 and s["hover_error_m"] < 0.02
    lines = robust_table({"protocol": {"lee": s}})
    assert lines[-1].startswith("| protocol | 1.00, ") and "cm" in lines[-1]
    assert set(CONDITIONS) >= {"protocol", "harsh", "any", "ground", "mass +30%", "wind 1 N"}


def test_the_rows_follow_the_airframe_flown():
    from bfc.config import airframe_params

    cf, hb = airframe_params("crazyflie"), AirframeParams()
    assert CONDITIONS["wind 1 N"].wind() == 1.0 and CONDITIONS["wind 2 N"].wind(hb) == 2.0
    assert CONDITIONS["wind 1 N"].wind(cf) == pytest.approx(cf.weight / hb.weight)  # the same share of its weight
    assert CONDITIONS["mass +30%"].flown_airframe(cf)["body_mass"] == pytest.approx(1.3 * cf.body_mass)
    flights = fly_condition("lee", "ground", 3, seconds=3.0, airframe=cf)
    z = flights.get(("state", "position"))[..., 2]
    assert z[:, 0].max() < 0.02 and (z[:, -1] > 1.3).all()  # from its own floor height up to the goal


def test_the_suite_figure_keeps_its_legend_off_the_bars(tmp_path, monkeypatch):
    """One legend above both panels: inside a panel it hid the first rows' bars."""
    from matplotlib.figure import Figure

    from bfc.evaluation.suites import robust_figure

    results = {row: {c: {"success_rate": 1.0, "hover_error_m": 0.004} for c in ("bfc", "lee")} for row in ("a", "b")}
    saved = []
    monkeypatch.setattr(Figure, "savefig", lambda fig, path, **kw: saved.append(fig))
    robust_figure(results, tmp_path / "robust.png")
    (fig,) = saved
    assert all(ax.get_legend() is None for ax in fig.axes)
    (legend,) = fig.legends
    assert [t.get_text() for t in legend.get_texts()] == ["bfc", "lee"]
    fig.canvas.draw()
    box = legend.get_window_extent()
    assert not any(box.overlaps(ax.get_window_extent()) for ax in fig.axes)
