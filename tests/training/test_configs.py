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


def test_the_schema_is_what_the_default_runs_and_extras_none_the_paper_variants():
    """`python train.py` runs the schema's defaults (conf/config.yaml and extras=robust add
    nothing); extras=none is the paper's BFC: the robust extras off, every other key equal."""
    from omegaconf import OmegaConf

    from bfc.config import Config

    robust, plain = compose_cfg(), compose_cfg(["extras=none"])
    schema = OmegaConf.structured(Config)
    assert robust == schema  # the defaults list adds nothing to the schema
    assert len(OmegaConf.load(ROOT / "conf" / "extras" / "robust.yaml") or {}) == 0  # comments only
    assert plain.variant == "jd_css_tdts" and plain == compose_cfg(["+ablation=jd_css_tdts"])
    assert robust.model.position_integral and not plain.model.position_integral
    assert tuple(robust.env.randomize.mass) == (0.7, 1.3) and robust.env.randomize.external_force == 1.0
    assert tuple(plain.env.randomize.mass) == (1.0, 1.0) and plain.env.randomize.external_force == 0.0
    assert robust.curriculum.frames > 0 and plain.curriculum.frames == 0
    assert robust.env.reward.angular_velocity == 0.001 and plain.env.reward.angular_velocity == 0.005
    assert list(robust.model.actor_hidden) == [128, 128] and list(plain.model.actor_hidden) == [64, 64]
    assert robust.loss.epochs == 2 and plain.loss.epochs == 4
    assert robust.jd.p_end == 0.75 and plain.jd.p_end == 0.0 and list(plain.jd.roll_range) == [-60.0, 60.0]
    changed = {k for k in robust if robust[k] != plain[k]}
    assert changed == {"variant", "model", "env", "jd", "curriculum", "optim", "loss"}
    # an ablation variant can still take them on explicitly
    assert compose_cfg(["+ablation=jd", "extras=robust"]).model.position_integral


@pytest.mark.parametrize("algo", ["ppo", "trpo", "ddpg"])
def test_every_algo_file_is_global_and_names_its_algorithm(algo):
    text = (ROOT / "conf" / "algo" / f"{algo}.yaml").read_text()
    assert text.startswith("# @package _global_")
    assert compose_cfg([f"algo={algo}"]).algo.name == algo


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


def one_line_error(r) -> str:
    assert r.returncode == 2, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: "), r.stderr[-2000:]
    return lines[0]


def test_unknown_key_fails():
    assert "unknown config key 'env.num_env'; env has: num_envs" in one_line_error(run_cli("env.num_env=3"))


def test_unknown_ablation_lists_the_valid_ones():
    line = one_line_error(run_cli("+ablation=jd_css_tdtss"))
    assert "ablation=jd_css_tdtss is not a config of conf/ablation/" in line and "jd_css_tdts" in line


@pytest.mark.parametrize(
    ("override", "moved_to"),
    [
        ("algo.max_kl=0.02", "algo.trpo.max_kl"),
        ("algo.tau=0.1", "algo.ddpg.tau"),
        ("eval.seed=3", "eval.validation_seed"),
        ("+algo.warmup_frames=7", "algo.ddpg.warmup_frames"),
    ],
)
def test_a_moved_key_fails_with_its_new_spelling(override, moved_to):
    line = one_line_error(run_cli(override))
    assert line == f"error: {override.lstrip('+').split('=')[0]} has moved: it is {moved_to} now"


def test_bad_override_syntax_is_one_line():
    assert "cannot parse the overrides" in one_line_error(run_cli("env.goal=[0,0"))


def test_negative_frames_fail_with_a_clear_message():
    assert "collector.total_frames must be > 0" in one_line_error(run_cli("collector.total_frames=-5"))


def test_missing_resume_dir_fails_cleanly():
    assert "no checkpoints/last.pt" in one_line_error(run_cli("resume=/nonexistent/run"))


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
