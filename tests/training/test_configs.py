"""Config composition, ablation files, validation of bad overrides (through the real CLI)."""

import subprocess
import sys

import pytest

from bfc.config import ABLATIONS, validate

from .helpers import ROOT, compose_cfg

SWITCHES = ("jd", "css", "tdts")


def test_default_is_the_full_bfc():
    cfg = compose_cfg()
    assert all(cfg[s].enabled for s in SWITCHES)
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
