"""The policy contract: one PolicySpec drives the env's maps, the file, the flight and the export."""

from pathlib import Path

import pytest
import torch

from bfc.agent import POLICY_FORMAT, PolicySpec, load_policy, read_policy, save_policy
from bfc.config import compose
from bfc.evaluation import fly, protocol_starts
from bfc.factory import find_transform, make_env
from bfc.transforms import MotorSpeedAction, PolicyObservation

V1 = Path(__file__).resolve().parents[1] / "data" / "policy_v1.pt"


def test_the_spec_of_a_config_is_what_the_env_and_the_file_carry(tmp_path):
    """Round trip: config -> spec -> env maps and network -> file -> spec -> flight env and export."""
    cfg = compose(["model.action_map=speed", "env.control_hz=50", "env.airframe.body_mass=0.75"])
    spec = PolicySpec.from_config(cfg)
    assert (spec.action_map, spec.control_hz, spec.position_integral) == ("speed", 50.0, True)
    env = make_env(cfg, num_envs=2, seed=0)
    observation, action = find_transform(env, PolicyObservation), find_transform(env, MotorSpeedAction)
    assert observation.size == spec.observation_size == env.reset()["observation"].shape[-1] == 41  # 22 + 3 + 16
    assert action.action_map == "speed" and action.hover_speed == spec.nominal_airframe.hover_speed
    env.close()
    torch.manual_seed(0)
    net = spec.make_net()
    path = tmp_path / "policy.pt"
    save_policy(path, spec, net, {"frames": 7})
    raw = torch.load(path, weights_only=True)  # data, never code
    assert raw["format"] == POLICY_FORMAT and set(raw) == {"format", "spec", "state_dict", "info"}
    loaded = read_policy(path)
    assert loaded.spec == spec and loaded.info == {"frames": 7}
    obs = torch.randn(5, spec.observation_size)
    assert torch.equal(loaded.net().mean(obs), net.mean(obs))
    flights = fly(path, protocol_starts(3), seconds=0.2)
    assert flights.shape == (3, 10)  # flown at the file's 50 Hz
    with pytest.raises(ValueError, match="trained at 50 Hz"):
        fly(path, protocol_starts(3), seconds=0.2, control_hz=100)
    pytest.importorskip("onnx")
    from bfc.export import export_onnx, read_metadata

    meta = read_metadata(export_onnx(path, tmp_path / "policy.onnx"))
    assert meta["control_hz"] == 50.0 and meta["action_map"] == "speed" and meta["position_integral"]
    assert meta["hover_speed"] == pytest.approx(spec.nominal_airframe.hover_speed)


def test_a_v1_policy_file_still_loads_through_the_legacy_reader(tmp_path):
    spec, net = load_policy(V1)
    assert spec.hidden == (16, 16) and spec.position_integral and spec.action_map == "thrust"
    assert spec.control_hz == 100.0 and spec.observation_size == 25
    raw = torch.load(V1, weights_only=True)
    assert raw["format"] == "bfc-policy-v1"
    torch.testing.assert_close(net.mlp[0].weight, raw["state_dict"]["mean.0.weight"], rtol=0, atol=0)
    # files written before the thrust map existed flew the speed map
    del raw["model"]["action_map"]
    torch.save(raw, tmp_path / "older.pt")
    assert load_policy(tmp_path / "older.pt")[0].action_map == "speed"


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        ({"format": "bfc-policy-v9", "spec": {}}, "found 'bfc-policy-v9'"),
        ({"frames": 3, "collector": {}}, "found a training checkpoint"),
        ({"format": POLICY_FORMAT, "spec": {"observation": "heading", "colour": "red"}}, "unknown fields"),
        ({"format": POLICY_FORMAT, "spec": {"hidden": [8]}, "state_dict": {}}, "do not match its spec"),
    ],
)
def test_a_file_that_is_no_policy_is_refused_with_one_line(tmp_path, payload, message):
    torch.save(payload, tmp_path / "x.pt")
    with pytest.raises(ValueError, match=message) as err:
        read_policy(tmp_path / "x.pt")
    assert "\n" not in str(err.value) and "is not a bfc policy file" in str(err.value)


def test_bad_spec_values_name_the_key():
    with pytest.raises(ValueError, match="model.action_map must be thrust or speed"):
        PolicySpec(action_map="rpm")
    with pytest.raises(ValueError, match="model.actor_hidden must be a non-empty list"):
        PolicySpec(hidden=())
    with pytest.raises(ValueError, match="airframe.body_mass must be > 0"):
        PolicySpec(airframe={"body_mass": 0.0})


def test_a_policy_file_carries_its_observation_constants_and_older_files_keep_theirs(tmp_path, monkeypatch):
    """The scales, clip and integral constants are the policy's: stored in its file, read by the
    maps and the exports from there (their parity on such a policy: tests/test_export*.py); a file
    written before they were stored keeps the values it was trained with, whatever the defaults."""
    from bfc.agent.policy_file import LEGACY_OBSERVATION_SCALES
    from bfc.export import export_c
    from bfc.transforms import OBSERVATION_SCALES
    from tests.export_helpers import SCALED, tiny_policy

    path = tiny_policy(tmp_path / "scaled.pt", scales=SCALED)
    assert torch.load(path, weights_only=True)["spec"]["observation_scales"] == SCALED
    spec = read_policy(path).spec
    observation = spec.make_observation_map(1)
    assert spec.observation_scales == SCALED and {k: getattr(observation, k) for k in SCALED} == SCALED
    header = export_c(path, tmp_path / "policy.h").read_text()
    assert "#define BFC_POLICY_POSITION_CLIP 0.5f /* m */" in header
    assert "#define BFC_POLICY_INTEGRAL_LIMIT 0.200000003f" in header  # float32's 0.2
    assert "#define BFC_POLICY_INTEGRAL_SETTLED_RADIUS_SQ 4.0f" in header
    older = torch.load(path, weights_only=True)  # as a v2 file written before the constants were stored
    seven = {k: v for k, v in SCALED.items() if not k.startswith("integral_settled")}
    older["spec"]["observation_scales"] = seven  # ... before the settled integration came
    torch.save(older, tmp_path / "seven.pt")
    assert read_policy(tmp_path / "seven.pt").spec.observation_scales == {
        **seven,
        "integral_settled_radius": LEGACY_OBSERVATION_SCALES["integral_settled_radius"],
        "integral_settled_speed": LEGACY_OBSERVATION_SCALES["integral_settled_speed"],
    }
    del older["spec"]["observation_scales"]
    torch.save(older, tmp_path / "older.pt")
    monkeypatch.setitem(OBSERVATION_SCALES, "position_clip", 9.0)  # a default changes ...
    assert PolicySpec().observation_scales["position_clip"] == 9.0
    assert read_policy(tmp_path / "older.pt").spec.observation_scales == LEGACY_OBSERVATION_SCALES  # ... not theirs
    assert read_policy(V1).spec.observation_scales == LEGACY_OBSERVATION_SCALES
    with pytest.raises(ValueError, match="observation_scales must be among position_clip"):
        PolicySpec(observation_scales={"position_clipp": 1.0})
