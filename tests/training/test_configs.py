"""Config composition, ablation files, validation of bad overrides (through the real CLI)."""

import subprocess
import sys

import pytest
import torch

from bfc.config import ABLATIONS, validate

from .helpers import ROOT, compose_cfg

SWITCHES = ("jd", "css", "tdts")


def test_default_is_the_full_bfc():
    cfg = compose_cfg()
    assert all(cfg[s].enabled for s in SWITCHES)
    assert cfg.variant == "jd_css_tdts_robust"
    for key in ("seed", "env.num_envs", "collector.total_frames", "collector.frames_per_batch"):
        node = cfg
        for part in key.split("."):
            node = node[part]
        assert node is not None


@pytest.mark.parametrize("name", ABLATIONS)
def test_each_ablation_switches_exactly_what_its_name_says(name):
    path = ROOT / "conf" / "ablation" / f"{name}.yaml"
    text = path.read_text()
    assert text.startswith("# @package _global_")
    for s in SWITCHES:
        assert f"{s}:\n  enabled:" in text, f"{name} must set {s}.enabled explicitly"
    cfg = compose_cfg([f"+ablation={name}"])
    parts = set(name.split("_")) - {"ppo"}
    assert {s for s in SWITCHES if cfg[s].enabled} == parts
    assert cfg.variant == name
    # the paper's variants leave bfc's robust extras out: the same task as extras=none
    plain = compose_cfg([f"+ablation={name}", "extras=none"])
    assert cfg == plain


def test_robust_extras_are_on_by_default_and_off_for_the_paper_variants():
    """The default = the paper's BFC + conf/extras/robust.yaml; extras=none is the paper's BFC:
    every other key equal, with the schema's (paper) values for what the extras change."""
    from omegaconf import OmegaConf

    from bfc.config import Config

    robust, plain = compose_cfg(), compose_cfg(["extras=none"])
    schema = OmegaConf.structured(Config)
    assert plain.variant == "jd_css_tdts" and plain == compose_cfg(["+ablation=jd_css_tdts"])
    assert robust.model.position_integral and not plain.model.position_integral
    assert tuple(robust.env.randomize.mass) == (0.7, 1.3) and robust.env.randomize.external_force == 1.0
    assert plain.env.randomize == schema.env.randomize and plain.jd == schema.jd and plain.optim == schema.optim
    assert robust.curriculum.frames > 0 and plain.curriculum == schema.curriculum and plain.curriculum.frames == 0
    assert robust.env.reward.angular_velocity < plain.env.reward.angular_velocity == schema.env.reward.angular_velocity
    assert list(robust.model.actor_hidden) == [128, 128] and list(plain.model.actor_hidden) == [64, 64]
    assert robust.loss.epochs == 3 and plain.loss == schema.loss
    changed = {k for k in robust if robust[k] != plain[k]}
    assert changed == {"variant", "model", "env", "jd", "curriculum", "optim", "loss"}
    # an ablation variant can still take them on explicitly
    assert compose_cfg(["+ablation=jd", "extras=robust"]).model.position_integral


def test_validate_names_the_key():
    cfg = compose_cfg(["collector.frames_per_batch=1000"])
    with pytest.raises(ValueError, match="collector.frames_per_batch"):
        validate(cfg)


def run_cli(*args):
    return subprocess.run(
        [sys.executable, "train.py", *args, "hydra.run.dir=/tmp/bfc-test-cli"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=120,
    )


def test_unknown_key_fails():
    r = run_cli("env.num_env=3")
    assert r.returncode != 0 and "num_env" in r.stderr


def test_unknown_ablation_lists_the_valid_ones():
    r = run_cli("+ablation=jd_css_tdtss")
    assert r.returncode != 0
    assert "jd_css_tdts" in r.stderr and "ppo" in r.stderr


def test_negative_frames_fail_with_a_clear_message():
    r = run_cli("collector.total_frames=-5")
    assert r.returncode != 0 and "collector.total_frames must be > 0" in r.stderr


def test_missing_resume_dir_fails_cleanly():
    r = run_cli("resume=/nonexistent/run")
    assert r.returncode != 0 and "no checkpoints/last.pt" in r.stderr


def test_paper_preset_sets_exactly_what_it_says():
    """+preset=paper: 250 Hz, 2x256 actor and critic, the 18-number odometry observation, the
    speed map, TDTS terminal, no robust extras; composable with an ablation variant; nothing else
    differs from the paper's BFC (extras=none)."""
    from bfc.factory import find_transform, make_env
    from bfc.transforms import MotorSpeedAction, PolicyObservation

    paper, plain = compose_cfg(["+preset=paper"]), compose_cfg(["extras=none"])
    assert paper.env.control_hz == 250.0 and paper.tdts.as_terminal
    assert list(paper.model.actor_hidden) == [256, 256] and list(paper.model.critic_hidden) == [256, 256]
    assert paper.model.observation == "odometry" and paper.model.action_map == "speed"
    assert not paper.model.position_integral and paper.env.randomize == plain.env.randomize
    expected = {
        "env.control_hz",
        "tdts.as_terminal",
        "model.actor_hidden",
        "model.critic_hidden",
        "model.observation",
        "model.action_map",
    }
    changed = {
        f"{s}.{k}"
        for s in plain
        if isinstance(plain[s], type(plain.env))
        for k in plain[s]
        if paper[s][k] != plain[s][k]
    }
    assert changed == expected
    with_jd = compose_cfg(["+preset=paper", "+ablation=jd"])
    assert with_jd.variant == "jd" and with_jd.env.control_hz == 250.0 and not with_jd.css.enabled
    paper.env.num_envs = 4
    env = make_env(paper, seed=0)
    assert env.base_env.control_hz == 250.0 and find_transform(env, MotorSpeedAction).action_map == "speed"
    obs = find_transform(env, PolicyObservation)
    td = env.reset()
    odometry, goal = td["odometry"], td["goal"]
    assert obs.size == 18
    torch.testing.assert_close(td["observation"], torch.cat((odometry[:, 0:3] - goal, odometry[:, 3:18]), -1))
