"""Airframes as data: the built-ins, a user's file, the layouts' physics, and the command line."""

import dataclasses
import subprocess
import sys

import pytest
import torch
import yaml

from bfc import keys
from bfc.config import (
    AIRFRAME_FILE_REQUIRED,
    airframe_params,
    builtin_airframes,
    compose,
    expand_airframe,
    load_airframe_file,
    validate,
)
from bfc.envs import AirframeParams, QuadrotorEnv

from ..training.helpers import ROOT


def test_the_built_ins_are_the_hummingbird_a_crazyflie_and_an_x500():
    assert builtin_airframes() == ["crazyflie", "hummingbird", "x500"]
    assert airframe_params("hummingbird") == AirframeParams()  # the default adds nothing
    cf, x500 = airframe_params("crazyflie"), airframe_params("x500")
    assert (cf.name, cf.layout, x500.layout) == ("crazyflie", "x", "x")
    assert 0.025 < cf.total_mass < 0.035 and 1.5 < x500.total_mass < 2.5
    # each lifts itself with room to spare, and hovers well below its top speed
    for a in (AirframeParams(), cf, x500):
        assert 1.5 < (a.max_rotor_speed / a.hover_speed) ** 2 < 4, a.name


def _write(path, fields):
    path.write_text(yaml.safe_dump(fields))
    return path


def test_an_airframe_file_round_trips(tmp_path):
    cf = {
        k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(airframe_params("crazyflie")).items()
    }
    path = _write(tmp_path / "crazyflie.yaml", cf)
    loaded = load_airframe_file(path)
    assert loaded == cf
    again = _write(tmp_path / "again.yaml", {k: v for k, v in loaded.items() if k != "name"})
    assert AirframeParams(**load_airframe_file(again)) == dataclasses.replace(AirframeParams(**cf), name="again")


def test_a_minimal_file_takes_neutral_values_not_the_hummingbirds(tmp_path):
    fields = {k: v for k, v in dataclasses.asdict(airframe_params("x500")).items() if k in AIRFRAME_FILE_REQUIRED}
    a = AirframeParams(**load_airframe_file(_write(tmp_path / "mine.yaml", fields)))
    assert a.name == "mine" and a.rotor_mass == a.imu_mass == a.rotor_drag_coefficient == 0.0
    assert a.gravity == 9.81 and a.rotor_spins == (1.0, -1.0, 1.0, -1.0)


@pytest.mark.parametrize(
    "change, named",
    [
        ({"body_mass": None}, "missing airframe field(s) body_mass"),
        ({"mass": 0.03}, "unknown airframe field 'mass'"),
        ({"body_mass": -1.0}, "env.airframe.body_mass"),
        ({"layout": "h"}, "env.airframe.layout must be '+' or 'x'"),
        ({"inertia": [1.0e-5, 1.0e-5, 5.0e-5]}, "env.airframe.inertia must be a rigid body's"),
        ({"max_rotor_speed": 1000.0}, "env.airframe.max_rotor_speed must be above the hover speed"),
        ({"rotor_spins": [1, 1, -1, -1]}, "env.airframe.rotor_spins"),
        ({"hull_half_size": [0.1, 0.1]}, "env.airframe.hull_half_size must be 3 numbers"),
    ],
)
def test_a_bad_file_fails_with_one_line_naming_the_field(tmp_path, change, named):
    fields = {
        k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(airframe_params("crazyflie")).items()
    }
    fields.update(change)
    fields = {k: v for k, v in fields.items() if v is not None}
    with pytest.raises(ValueError) as err:
        load_airframe_file(_write(tmp_path / "bad.yaml", fields))
    message = str(err.value)
    assert named in message and "\n" not in message and str(tmp_path / "bad.yaml") in message


def _rates_after(airframe: AirframeParams, extra: torch.Tensor, steps: int = 5) -> torch.Tensor:
    """Body rates after `steps` control steps at hover speed plus `extra` (4,) rad/s per motor,
    from a level hover in mid-air."""
    env = QuadrotorEnv(1, airframe=airframe, start_motors="hover", num_threads=1)
    start = torch.zeros(1, 12)
    start[0, 2] = 1.5
    td = env.reset(env.reset().set(keys.START_STATE, start))
    action = (airframe.hover_speed + extra).reshape(1, 4).float()
    for _ in range(steps):
        td = env.step(td.set(keys.ACTION, action))["next"]
    return td.get(keys.STATE).get("angular_velocity")[0]


@pytest.mark.parametrize("name", ["hummingbird", "crazyflie"])
def test_rotors_push_where_they_sit_and_react_against_their_spin(name):
    """The physics of both layouts, from the rotors' positions and spins alone: speeding up the
    rotors on the +y side rolls the body +x, those ahead of the centre pitch it -y (nose up), the
    clockwise ones yaw it +z (their reaction is counter-clockwise)."""
    a = airframe_params(name)
    xy = torch.tensor([p[:2] for p in a.rotor_positions])
    spins = torch.tensor(a.rotor_spins)
    delta = 0.02 * a.hover_speed
    roll = _rates_after(a, delta * (xy[:, 1] > 1e-9).float())
    pitch = _rates_after(a, delta * (xy[:, 0] > 1e-9).float())
    yaw = _rates_after(a, delta * (spins > 0).float())
    assert roll[0] > 0 and abs(roll[1]) < 1e-3 * roll[0]
    assert pitch[1] < 0 and abs(pitch[0]) < -1e-3 * pitch[1]
    assert yaw[2] > 0 and abs(yaw[0]) + abs(yaw[1]) < 1e-3 * yaw[2]


@pytest.mark.parametrize("name", ["hummingbird", "crazyflie"])
def test_the_mixer_commands_what_the_physics_then_does(name):
    from bfc.controllers.mixer import Mixer

    a = airframe_params(name)
    mixer = Mixer(a)
    hover = torch.tensor([a.weight], dtype=torch.float64)
    for axis in range(3):
        torque = torch.zeros(1, 3, dtype=torch.float64)
        torque[0, axis] = 1e-3 * a.weight * a.arm_length
        speeds = mixer(hover, torque)[0]
        rates = _rates_after(a, (speeds - a.hover_speed).float(), steps=3)
        assert rates[axis] > 0 and all(abs(rates[k]) < 0.05 * rates[axis] for k in range(3) if k != axis), rates


def test_the_env_rests_each_airframe_on_its_own_hull():
    for name in builtin_airframes():
        a = airframe_params(name)
        env = QuadrotorEnv(8, airframe=a, num_threads=1)
        z = env.reset().get(keys.STATE).get("position")[:, 2]
        torch.testing.assert_close(z, torch.full((8,), a.hull_half_size[2]))
        assert env.model.geom("hull").size.tolist() == pytest.approx(list(a.hull_half_size))


def test_the_command_line_names_an_airframe_or_a_file(tmp_path):
    assert expand_airframe(["seed=1", "env.airframe=crazyflie"]) == ["seed=1", "env/airframe=crazyflie"]
    assert expand_airframe(["env.airframe=hummingbird,x500"]) == ["env/airframe=hummingbird,x500"]
    cfg = compose(["env.airframe=crazyflie", "env.airframe.body_mass=0.031"])
    assert cfg.env.airframe.name == "crazyflie" and cfg.env.airframe.body_mass == 0.031
    assert cfg.env.randomize.external_force == pytest.approx(0.04)  # the wind follows the weight
    fields = {
        k: (list(v) if isinstance(v, tuple) else v) for k, v in dataclasses.asdict(airframe_params("x500")).items()
    }
    path = _write(tmp_path / "mine.yaml", {k: v for k, v in fields.items() if k != "name"})
    cfg = compose([f"env.airframe={path}", "env.airframe.max_rotor_speed=1100.0"])
    assert cfg.env.airframe.name == "mine" and cfg.env.airframe.max_rotor_speed == 1100.0
    assert cfg.env.airframe.inertia == fields["inertia"]
    for bad, says in (
        ("env.airframe=nosuch", "is not an airframe"),
        (f"env.airframe={tmp_path / 'none.yaml'}", "no such file"),
        ("env.airframe=crazyflie,nosuch", "env.airframe=nosuch is not an airframe"),
    ):
        with pytest.raises(ValueError, match=says):
            expand_airframe([bad])


def test_a_wind_too_strong_for_the_airframe_is_refused():
    cfg = compose(["env.airframe=crazyflie", "env.randomize.external_force=1.0"])
    with pytest.raises(ValueError, match="env.randomize.external_force must be at most 50% of the airframe's weight"):
        validate(cfg)
    validate(compose(["env.airframe=crazyflie"]))


def test_randomised_airframes_that_cannot_lift_themselves_are_refused():
    """The Crazyflie at the firmware's thrust (thrust-to-weight 1.53) with the default's mass and k_f
    ranges would draw bodies of 0.94: refused, naming the ranges; its own narrower ones pass."""
    cfg = compose(["env.airframe=crazyflie", "env.randomize.mass=[0.7,1.3]", "env.randomize.motor_constant=[0.8,1.2]"])
    with pytest.raises(ValueError, match=r"env.randomize.mass must be ranges .* thrust-to-weight 0.94 at mass x1.3"):
        validate(cfg)
    validate(compose(["env.airframe=crazyflie"]))
    validate(compose([]))
    floor = ["env.airframe=crazyflie", "env.randomize.mass=[0.7,1.3]", "env.randomize.motor_constant=[0.8,1.2]"]
    validate(compose([*floor, "env.randomize.min_thrust_to_weight=1.15"]))  # a floor above 1 lifts every draw
    with pytest.raises(ValueError, match=r"min_thrust_to_weight must be below the airframe's own .* 1.53"):
        validate(compose([*floor, "env.randomize.min_thrust_to_weight=1.6"]))


def test_a_thrust_to_weight_floor_strengthens_only_the_motors_of_weaker_draws():
    """mass x0.7-1.3 and k_f x0.8-1.2 on the Crazyflie (1.53) draw bodies down to 0.94; with a
    floor of 1.15 those get a larger k_f until they reach it, every other draw is left as it was."""
    from bfc.config import airframe_params
    from bfc.envs import QuadrotorEnv

    cf = airframe_params("crazyflie")
    ranges = {"mass": (0.7, 1.3), "motor_constant": (0.8, 1.2)}

    def drawn(**floor):
        env = QuadrotorEnv(256, airframe=cf, randomize={**ranges, **floor}, seed=5)
        env.reset()
        scale = env.airframe_scale
        env.close()
        return scale, cf.thrust_to_weight * scale["motor_constant"] * cf.mass_gain(scale["mass"])

    free, free_ratio = drawn()
    held, held_ratio = drawn(min_thrust_to_weight=1.15)
    weak = free_ratio < 1.15
    assert weak.any() and (~weak).any() and free_ratio.min() < 1.0  # some draws could not lift themselves
    assert held_ratio.min() >= 1.15 - 1e-9 and torch.allclose(held_ratio[weak], torch.full_like(held_ratio[weak], 1.15))
    assert torch.equal(held["mass"], free["mass"])  # the same draws: only the weak ones' k_f moved
    assert torch.equal(held["motor_constant"][~weak], free["motor_constant"][~weak])


def test_train_py_reports_a_bad_airframe_in_one_line(tmp_path):
    bad = _write(tmp_path / "bad.yaml", {"body_mass": 0.03})
    for arg, says in ((f"env.airframe={bad}", "missing airframe field(s)"), ("env.airframe.layout=y", "layout")):
        run = subprocess.run(
            [sys.executable, "train.py", arg, "collector.total_frames=512"], cwd=ROOT, capture_output=True, text=True
        )
        lines = [ln for ln in run.stderr.splitlines() if ln.startswith("error:")]
        assert run.returncode == 2 and len(lines) == 1 and says in lines[0], run.stderr[-2000:]
        assert "Traceback" not in run.stderr
