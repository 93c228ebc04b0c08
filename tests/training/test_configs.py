"""Config composition, ablation files, validation of bad overrides (through the real CLI)."""

import pickle
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
    assert robust.env.reward.precision_radius == 0.03 and plain.env.reward.precision_radius == 0.1
    assert list(robust.model.actor_hidden) == [128, 128] and list(plain.model.actor_hidden) == [64, 64]
    assert robust.loss.epochs == 2 and plain.loss.epochs == 4
    assert robust.jd.p_end == 0.75 and plain.jd.p_end == 0.0 and list(plain.jd.roll_range) == [-60.0, 60.0]
    # the default trains through latency; the paper's BFC flies a prompt estimate
    assert list(robust.latency.observation_steps) == [0, 5] and robust.latency.action_steps == 1
    assert plain.latency.observation_steps == 0 and plain.latency.action_steps == 0
    assert robust.model.command_history == 4 and plain.model.command_history == 0
    assert robust.optim.desired_kl == 0.05 and plain.optim.desired_kl is None
    assert robust.loss.entropy_coeff == 0.004 and plain.loss.entropy_coeff == 0.0
    changed = {k for k in robust if robust[k] != plain[k]}
    assert changed == {"variant", "model", "env", "jd", "curriculum", "optim", "loss", "latency"}
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


@pytest.mark.parametrize(
    ("override", "allowed"),
    [("loss.implementation=autograd", "'bfc' or 'torchrl'"), ("torch_threads=-1", "0 \\(every core\\) or >= 1")],
)
def test_validate_names_what_a_key_allows(override, allowed):
    with pytest.raises(ValueError, match=allowed):
        validate(compose_cfg([override]))


def test_the_paper_preset_gives_its_update_every_core():
    """It collects in the learner's process, so the update's threads (null) are every core."""
    paper, default = compose_cfg(["+preset=paper"]), compose_cfg([])
    assert paper.collector.workers == 0 and paper.torch_threads is None and default.collector.workers == 1


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
    line = one_line_error(run_cli("env.num_env=3"))
    assert "unknown config key 'env.num_env' (did you mean env.num_envs?); env has: " in line
    assert ", num_envs," in line


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


@pytest.mark.parametrize(
    "override, message",
    [
        ("model=3", "error: model is a config section, not a value (got 3): set its keys (model.actor_hidden"),
        ("env=foo", "error: env is a config section, not a value (got 'foo'): set its keys (env.control_hz"),
        ("optim=fast", "error: optim is a config section, not a value (got 'fast')"),
        ("loss.epochs=2.5", "error: loss.epochs takes an integer, got 2.5"),
        ("seed=0,abc", "error: seed takes an integer, got 'abc'"),
        ("loss.gamma=null", "error: loss.gamma cannot be null; it takes a number"),
        ("logger.video=maybe", "error: logger.video takes true or false, got 'maybe'"),
        ("model.actor_hidden=64", "error: model.actor_hidden takes a list ([a, b, ...]), got 64"),
        ("hydra/launcher=nosuch", "error: hydra/launcher=nosuch names no launcher; available: basic, joblib, ray"),
        ("hydra/sweeper=nosuch", "error: hydra/sweeper=nosuch names no sweeper; available: basic, optuna"),
    ],
)
def test_a_value_of_the_wrong_type_a_section_or_an_unknown_plugin_is_one_line(override, message):
    assert one_line_error(run_cli(override)).startswith(message)


def test_values_omegaconf_converts_still_pass():
    """What OmegaConf merges stays accepted: a quoted number, 1 for true, a dict for a section, a
    null where optional, sweeps."""
    from bfc.config import check_overrides

    check_overrides(["loss.epochs='3'", "logger.video=1", "model={actor_hidden:[64,64]}", "optim.desired_kl=null"])
    check_overrides(["optim.lr=1e-3", "optim.lr=interval(0.0005,0.003)", "seed=range(0,3)", "noise.std=[0.1,0.2]"])


def test_bad_override_syntax_is_one_line():
    assert "cannot parse the overrides" in one_line_error(run_cli("env.goal=[0,0"))


def test_negative_frames_fail_with_a_clear_message():
    assert "collector.total_frames must be > 0" in one_line_error(run_cli("collector.total_frames=-5"))


@pytest.mark.parametrize(
    "overrides, message",
    [
        (["loss.mirror_coeff=-1"], "error: loss.mirror_coeff must be a number >= 0 (0: off), got -1.0"),
        (
            ["loss.mirror_coeff=1", "algo=trpo"],
            "error: loss.mirror_coeff must be 0 with algo=trpo (the mirror loss is PPO's)",
        ),
        (["loss.mirror_reflections=some"], "error: loss.mirror_reflections must be 'all' or 'one', got 'some'"),
        (["loss.mirror_from_frames=-1"], "error: loss.mirror_from_frames must be an integer >= 0"),
        (["loss.mirror_max_tilt=0"], "error: loss.mirror_max_tilt must be degrees in (0, 180]"),
        (["loss.mirror_max_tilt=200"], "error: loss.mirror_max_tilt must be degrees in (0, 180]"),
        (["loss.mirror_from_frames=1.5e6"], "error: loss.mirror_from_frames takes an integer, got 1500000.0"),
    ],
)
def test_a_bad_mirror_setting_is_one_line(overrides, message):
    assert one_line_error(run_cli(*overrides)).startswith(message)


def test_missing_resume_dir_fails_cleanly():
    assert "no checkpoints/last.pt" in one_line_error(run_cli("resume=/nonexistent/run"))


# What each paper preset sets, with where the value comes from (the presets' comments cite the
# same): the paper, and OpenAI Baselines' defaults at ea25b9e for what the paper leaves open.
PAPER_COMMON = {
    "env.control_hz": 250.0,  # sec. 6.3
    "model.observation": "odometry",  # sec. 5
    "model.action_map": "speed",  # sec. 6.3
    "model.activation": "tanh",  # Baselines' mlp()
    "model.normalize_observation": True,  # run.py: VecNormalize
    "optim.normalize_reward": True,  # VecNormalize(ret=True)
    "tdts.as_terminal": True,  # Algorithm 1
    "env.reward.kind": "paper",  # sec. 6.4 (conf/reward/paper.yaml)
    "env.reward.position": 1.0,
    "env.reward.tilt": 0.5,
    "env.reward.yaw": 0.1,
    "env.reward.crash_penalty": 1200.0,
    "env.reward.scale": 0.01,
}
PAPER_PRESETS = {
    "paper": {  # ppo2/defaults.py mujoco(), ppo2.py learn(), model.py
        "model.actor_hidden": [256, 256],
        "model.critic_hidden": [256, 256],
        "model.init_std": 1.0,
        "collector.frames_per_batch": 8192,
        "loss.kind": "clip",
        "loss.gamma": 0.99,
        "loss.lmbda": 0.95,
        "loss.clip_epsilon": 0.2,
        "loss.clip_value": 0.2,
        "loss.epochs": 10,
        "loss.num_minibatches": 32,
        "loss.entropy_coeff": 0.0,
        "loss.critic_coeff": 0.25,
        "loss.critic_loss": "l2",
        "optim.lr": 3e-4,
        "optim.anneal_lr": True,
        "optim.max_grad_norm": 0.5,
        "optim.adam_eps": 1e-5,
        "collector.workers": 0,  # on-policy, as Baselines; the update gets every core (bfc's choice)
    },
    "paper_trpo": {  # trpo_mpi/defaults.py mujoco(), trpo_mpi.py learn()
        "algo.name": "trpo",
        "model.actor_hidden": [64, 64],
        "model.critic_hidden": [64, 64],
        "model.init_std": 1.0,
        "collector.frames_per_batch": 1024,
        "algo.trpo.max_kl": 0.01,
        "algo.trpo.cg_iterations": 10,
        "algo.trpo.damping": 0.1,
        "algo.trpo.gamma": 0.99,
        "algo.trpo.lmbda": 0.98,
        "algo.trpo.critic_epochs": 5,
        "algo.trpo.critic_minibatches": 16,
        "optim.lr": 1e-3,
        "optim.anneal_lr": False,
        "optim.adam_eps": 1e-8,
    },
    "paper_ddpg": {  # ddpg/ddpg.py learn()
        "algo.name": "ddpg",
        "model.actor_hidden": [400, 400],
        "model.critic_hidden": [400, 400],
        "model.init_std": 0.2,
        "model.squash": True,
        "collector.frames_per_batch": 2048,
        "algo.ddpg.batch_size": 64,
        "algo.ddpg.tau": 0.01,
        "algo.ddpg.actor_lr": 1e-4,
        "algo.ddpg.critic_lr": 1e-3,
        "algo.ddpg.gamma": 0.99,
        "algo.ddpg.buffer_size": 1_000_000,
        "algo.ddpg.updates_per_batch": 1024,
        "algo.ddpg.warmup_frames": 0,
        "optim.anneal_lr": False,
        "optim.max_grad_norm": 1e6,
    },
}


def _flat(cfg, prefix=""):
    from omegaconf import OmegaConf

    out = {}
    for key, value in (OmegaConf.to_container(cfg) if not isinstance(cfg, dict) else cfg).items():
        if isinstance(value, dict):
            out.update(_flat(value, f"{prefix}{key}."))
        else:
            out[f"{prefix}{key}"] = value
    return out


@pytest.mark.parametrize("preset", sorted(PAPER_PRESETS))
def test_paper_preset_sets_each_cited_value_and_nothing_else(preset):
    """Each paper preset sets every value its comments cite (the paper's, Baselines' defaults), on
    top of the paper's BFC without bfc's extras (extras=none) and nothing else; an ablation
    variant composes with it."""
    expected = {**PAPER_COMMON, **PAPER_PRESETS[preset]}
    algo = PAPER_PRESETS[preset].get("algo.name", "ppo")
    paper = _flat(compose_cfg([f"+preset={preset}"]))
    plain = _flat(compose_cfg(["extras=none", f"algo={algo}"]))
    for key, value in expected.items():
        assert paper[key] == value, key
    changed = {k for k in plain if paper[k] != plain[k]}
    assert changed <= set(expected), changed - set(expected)
    assert paper["variant"] == "jd_css_tdts" and paper["jd.enabled"] and not paper["model.position_integral"]
    with_jd = _flat(compose_cfg([f"+preset={preset}", "+ablation=jd"]))
    assert with_jd["variant"] == "jd" and not with_jd["css.enabled"]
    assert {k: with_jd[k] for k in expected} == expected


LATENCY_RECIPE = {
    "latency.observation_steps": [0, 5],
    "latency.action_steps": 1,
    "model.command_history": 4,
    "loss.entropy_coeff": 0.004,
    "optim.desired_kl": 0.05,
    "env.reward.precision_radius": 0.03,
    "jd.velocity_range": [-3.0, 3.0],
    "jd.angular_velocity_range": [-230.0, 230.0],
}


def test_latency_preset_is_the_default_and_adds_the_recipe_elsewhere():
    """+preset=latency: the measured latency recipe (docs/training.md), which the default trains:
    on the default it changes nothing; on the paper's BFC it adds the recipe and nothing else."""
    default = _flat(compose_cfg())
    assert {k: default[k] for k in LATENCY_RECIPE} == LATENCY_RECIPE and default["latency.curriculum"] is True
    assert _flat(compose_cfg(["+preset=latency"])) == default
    plain, added = (
        _flat(compose_cfg(["+ablation=jd_css_tdts"])),
        _flat(compose_cfg(["+ablation=jd_css_tdts", "+preset=latency"])),
    )
    assert {k: added[k] for k in LATENCY_RECIPE} == LATENCY_RECIPE
    assert {k for k in plain if added[k] != plain[k]} == set(LATENCY_RECIPE)
    validate(compose_cfg(["+ablation=jd_css_tdts", "+preset=latency"]))


def test_prompt_preset_is_the_default_before_latency_training():
    """+preset=prompt: the previous default (a prompt estimate): the recipe's keys back, nothing else."""
    expected = {
        "latency.observation_steps": 0,
        "latency.action_steps": 0,
        "model.command_history": 0,
        "loss.entropy_coeff": 0.0,
        "optim.desired_kl": None,
        "env.reward.precision_radius": 0.1,
        "jd.velocity_range": [-1.0, 1.0],
        "jd.angular_velocity_range": [-115.0, 115.0],
    }
    prompt, default = _flat(compose_cfg(["+preset=prompt"])), _flat(compose_cfg())
    assert {k: prompt[k] for k in expected} == expected
    assert {k for k in default if prompt[k] != default[k]} == set(LATENCY_RECIPE)
    validate(compose_cfg(["+preset=prompt", "algo=trpo"]))


def test_a_paper_preset_beside_another_algorithm_names_the_right_preset():
    err = one_line_error(run_cli("+preset=paper", "algo=trpo"))
    assert "use +preset=paper_trpo" in err


def test_paper_preset_builds_the_env_it_says():
    """+preset=paper's env: 250 Hz, the speed map, the 18 odometry numbers relative to the goal."""
    from bfc.factory import find_transform, make_env
    from bfc.transforms import MotorSpeedAction, PolicyObservation

    paper = compose_cfg(["+preset=paper"])
    paper.env.num_envs = 4
    env = make_env(paper, seed=0)
    assert env.base_env.control_hz == 250.0 and find_transform(env, MotorSpeedAction).action_map == "speed"
    obs = find_transform(env, PolicyObservation)
    td = env.reset()
    odometry, goal = td["odometry"], td["goal"]
    assert obs.size == 18
    torch.testing.assert_close(td["observation"], torch.cat((odometry[:, 0:3] - goal, odometry[:, 3:18]), -1))


def test_a_policys_observation_constants_are_set_by_key_and_stored_with_it():
    """`model.observation_scales.<name>` (no "+") sets one constant of the policy's maps; the rest
    stay the defaults; the spec (and so the policy file and the exports) carries them; a misspelt
    name or a value <= 0 is one line."""
    from bfc.agent import PolicySpec
    from bfc.keys import OBSERVATION_SCALE_NAMES
    from bfc.transforms import OBSERVATION_SCALES

    assert tuple(OBSERVATION_SCALES) == OBSERVATION_SCALE_NAMES  # one list of names, torch-free for the config
    cfg = compose_cfg(["model.observation_scales.integral_settled_radius=0.3"])
    validate(cfg)
    cfg = pickle.loads(pickle.dumps(cfg))  # as launchers and collection workers receive it
    spec = PolicySpec.from_config(cfg)
    assert spec.observation_scales == {**OBSERVATION_SCALES, "integral_settled_radius": 0.3}
    assert spec.make_observation_map(2).integral_settled_radius == 0.3
    assert PolicySpec.from_config(compose_cfg([])).observation_scales == OBSERVATION_SCALES
    r = run_cli("model.observation_scales.integral_radiuss=0.3")
    assert "unknown config key 'model.observation_scales.integral_radiuss'" in one_line_error(r)
    r = run_cli("model.observation_scales.integral_limit=0")
    assert one_line_error(r) == "error: model.observation_scales.integral_limit must be > 0 or null, got 0.0"
