"""What a new user meets first: the import paths, composing configs, clear errors, no global side effects."""

import importlib.util
import runpy
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
import torch

ROOT = Path(__file__).resolve().parents[1]


def fresh_python(code: str, timeout: int = 300) -> subprocess.CompletedProcess:
    """Run `code` in a new interpreter (so import order is the test's, not pytest's)."""
    return subprocess.run(
        [sys.executable, "-c", textwrap.dedent(code)], cwd=ROOT, capture_output=True, text=True, timeout=timeout
    )


def cli(script: str, *args, timeout: int = 300) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, script, *args, "hydra.run.dir=/tmp/bfc-test-cli"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def test_make_env_and_fly_are_functions_in_any_import_order():
    r = fresh_python(
        """
        import bfc.training, bfc.evaluation, bfc.factory
        import bfc
        from omegaconf import OmegaConf
        from bfc.config import Config
        cfg = OmegaConf.structured(Config)
        cfg.env.num_envs = 2
        for _ in range(3):
            env = bfc.make_env(cfg, seed=0)
            assert env.reset()["observation"].shape == (2, 41)  # the default: 22 + the integral + 4 commands
            env.close()
        import bfc.evaluation.flights
        from bfc.evaluation import fly, protocol_starts
        assert callable(bfc.evaluation.fly) and bfc.evaluation.fly is fly
        for _ in range(2):
            assert fly("lee", protocol_starts(2), seconds=0.1).shape == (2, 25)
        print("ok")
        """
    )
    assert r.returncode == 0 and r.stdout.strip() == "ok", r.stderr[-2000:]


def test_compose_works_from_a_fresh_interpreter_after_importing_bfc_config():
    r = fresh_python(
        """
        import bfc.config
        cfg = bfc.config.compose(["+ablation=jd", "seed=4"])
        assert cfg.variant == "jd" and cfg.seed == 4 and not cfg.css.enabled
        # Hydra's own compose finds the registered schema too
        from hydra import compose, initialize_config_dir
        with initialize_config_dir(config_dir=str(bfc.config.CONF_DIR), version_base="1.3"):
            assert compose("config").env.num_envs == 256
        print(bfc.config.compose([], config_name="evaluate").eval.seed)
        """
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "0"  # evaluate.py reports on the test starts


@pytest.mark.parametrize(
    "override, key",
    [
        ("+env.num_envz=3", "env.num_envz"),
        ("+presets=paper", "presets"),
        ("+loss.minibatchsize=7", "loss.minibatchsize"),
    ],
)
def test_a_plus_override_that_names_no_key_is_an_error(override, key):
    from bfc.config import compose

    with pytest.raises(ValueError, match=f"unknown config key '{key}'"):
        compose([override])


def test_train_rejects_an_unknown_plus_key_with_a_one_line_error():
    r = cli("train.py", "+env.num_envz=3")
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == [r.stderr.strip()]  # one line
    assert "unknown config key 'env.num_envz'" in r.stderr and "num_envs" in r.stderr


@pytest.mark.parametrize(
    "override, message",
    [
        ("env.num_envs=0", "env.num_envs must be an integer >= 1, got 0"),
        ("env.goal=[nan,0,1.5]", "env.goal must be 3 finite numbers"),
        ("loss.num_minibatches=0", "loss.num_minibatches must be in [1, collector.frames_per_batch=8192]"),
        ("eval.threshold=0", "eval.threshold must be > 0"),
    ],
)
def test_bad_training_values_exit_2_with_the_key_named(override, message):
    small = [] if "num_envs" in override else ["env.num_envs=16"]
    r = cli("train.py", override, "collector.total_frames=256", *small)
    assert r.returncode == 2, r.stderr[-2000:]
    assert message in r.stderr and "Traceback" not in r.stderr


def test_a_smaller_batch_alone_is_a_valid_config():
    from bfc.config import compose, minibatch_size, validate

    cfg = compose(["collector.frames_per_batch=2048"])
    validate(cfg)
    assert minibatch_size(cfg) == 128  # follows the batch: 16 minibatches
    cfg = compose(["loss.minibatch_size=1000"])
    assert minibatch_size(cfg) == 1000


def test_jd_decay_follows_the_run_length_unless_set():
    from bfc.config import compose
    from bfc.factory import find_transform, make_env
    from bfc.transforms import JumpingDistribution

    # null follows the run: p falls to jd.p_end (0.75 by default, 0 in the paper's variants) as it ends
    cases = (
        (["extras=none", "collector.total_frames=3000000"], 3_000_000, 0.0),
        (["extras=none", "jd.decay_frames=6"], 6, 0.0),
        (["collector.total_frames=3000000"], 3_000_000, 0.75),
    )
    for overrides, expected, p_end in cases:
        env = make_env(compose([*overrides, "env.num_envs=2"]))
        jd = find_transform(env, JumpingDistribution)
        assert jd.decay_frames == expected and jd.probability_at(expected) == p_end
        assert jd.probability_at(expected // 2) == pytest.approx((1 + p_end) / 2)
        env.close()


def test_a_nan_goal_is_named_as_a_goal_problem():
    from bfc.evaluation import fly, protocol_starts

    with pytest.raises(ValueError, match="goal must be finite"):
        fly("lee", protocol_starts(2), goal=(float("nan"), 0.0, 1.5), seconds=0.1)


def test_transform_seeds_do_not_depend_on_their_place_in_the_stack():
    from bfc.config import compose
    from bfc.factory import find_transform, make_env
    from bfc.transforms import ControlledStartingState, JumpingDistribution

    draws = {}
    for tdts in ("true", "false"):
        env = make_env(compose(["env.num_envs=8", f"tdts.enabled={tdts}"]), seed=5)
        draws[tdts] = [
            find_transform(env, cls).generator.get_state() for cls in (JumpingDistribution, ControlledStartingState)
        ]
        env.close()
    assert all(torch.equal(a, b) for a, b in zip(draws["true"], draws["false"], strict=True))


def test_env_state_dict_restores_a_rollout_bit_identically():
    from bfc.config import compose
    from bfc.factory import make_env

    env = make_env(compose(["env.num_envs=4"]), seed=1)
    td = env.reset()
    for _ in range(5):
        td = env.step_and_maybe_reset(td.set("action", torch.rand(4, 4) * 2 - 1))[1]
    snapshot = {k: v.clone() if isinstance(v, torch.Tensor) else v for k, v in env.state_dict().items()}
    actions = torch.rand(30, 4, 4) * 2 - 1

    def roll(td):
        out = []
        for a in actions:
            data, td = env.step_and_maybe_reset(td.clone().set("action", a))
            out.append(data["next", "observation"])
        return torch.stack(out)

    first = roll(td.clone())
    env.load_state_dict(snapshot)
    assert torch.equal(roll(td.clone()), first)
    env.close()


def test_library_code_leaves_backend_and_threads_alone(tmp_path):
    r = fresh_python(
        """
        import sys
        import matplotlib
        raw = lambda: dict.__getitem__(matplotlib.rcParams, "backend")  # without resolving it
        before = raw()
        import bfc.evaluation.report, bfc.evaluation.plots, bfc.training
        assert "matplotlib.pyplot" not in sys.modules, "library code imported pyplot"
        print(raw() == before)
        """
    )
    assert r.returncode == 0 and r.stdout.strip() == "True", r.stderr[-2000:]

    from bfc.training import train

    from .training.helpers import TINY, compose_cfg

    torch.set_num_threads(2)
    train(compose_cfg([*TINY, "collector.total_frames=512", "env.episode_seconds=0.2"]), tmp_path)
    assert torch.get_num_threads() == 2


def test_training_never_imports_the_classical_controllers(tmp_path):
    r = fresh_python(
        f"""
        import sys
        from pathlib import Path
        from bfc.training import train
        from tests.training.helpers import TINY, compose_cfg
        train(compose_cfg([*TINY, "collector.total_frames=512", "env.episode_seconds=0.2"]), {str(tmp_path)!r})
        loaded = [m for m in ("bfc.controllers", "osqp", "scipy", "pandas", "ray", "boto3") if m in sys.modules]
        print(loaded, (Path({str(tmp_path)!r}) / "tb").is_dir())
        import importlib.util  # TensorBoard's S3 support is kept out of training only: found after
        print(importlib.util.find_spec("boto3") is not None)
        """
    )
    assert r.returncode == 0, r.stderr[-2000:]
    installed = importlib.util.find_spec("boto3") is not None  # with the ray extra
    assert r.stdout.strip().splitlines()[-2:] == ["[] True", str(installed)]


@pytest.mark.parametrize(
    "args, message",
    [
        (["policy=pretrained/policy.pt", "runs=/tmp"], "runs only apply with suite=paper"),
        (["suite=paper", "policy=pretrained/policy.pt", "noise.kind=ou"], "noise do not apply with suite=paper"),
        (["suite=paper", "policy=pretrained/policy.pt", "eval.hold_seconds=20"], "eval.hold_seconds must be in"),
        (["policy=pretrained/policy.pt", "+eval.interval_frames=5"], "unknown config key 'eval.interval_frames'"),
        (["suite=storm", "policy=pretrained/policy.pt"], "suite must be one of paper, robust"),
        (["suite=robust", "policy=pretrained/policy.pt", "runs=/tmp"], "runs only applies with suite=paper"),
    ],
)
def test_evaluate_honours_or_rejects_every_key(args, message):
    """(A key that is not in the schema at all, without `+`, is Hydra's own error: see test_configs.)"""
    r = cli("evaluate.py", *args)
    assert r.returncode == 2, r.stderr[-2000:]
    assert message in r.stderr and "Traceback" not in r.stderr


def test_checking_a_command_line_loads_no_torch_and_knows_every_controller():
    """Bad input fails at once: the config, its checks and the CLI helpers import no torch, TorchRL
    or MuJoCo, and the controller names they check against are the controllers' registry."""
    r = fresh_python(
        """
        import sys
        import bfc.cli, bfc.config, bfc.sweeps
        print([m for m in ("torch", "torchrl", "mujoco", "tensordict") if m in sys.modules])
        """
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip() == "[]"
    from bfc.config import CONTROLLER_NAMES
    from bfc.controllers import CONTROLLERS

    assert sorted(CONTROLLER_NAMES) == sorted(CONTROLLERS)


@pytest.mark.parametrize("script", sorted(p.name for p in (ROOT / "bench").glob("*.py")))
def test_every_benchmark_explains_itself(script, monkeypatch, capsys):
    """`bench/X.py --help` (run in this process) prints its usage: a '%' in a help string once made it a traceback."""
    monkeypatch.setattr(sys, "argv", [script, "--help"])
    monkeypatch.syspath_prepend(str(ROOT / "bench"))
    with pytest.raises(SystemExit) as exit_:
        runpy.run_path(str(ROOT / "bench" / script), run_name="__main__")
    assert exit_.value.code == 0
    assert "usage:" in capsys.readouterr().out


def test_train_py_holds_the_garbage_collector_only_while_it_imports(tmp_path):
    # train.py's launch runs without Python's cyclic collector (bfc.imports); training, and every
    # process it forks (the collector's worker, the background evaluator), runs with it on
    r = fresh_python(
        f"""
        import gc, runpy, sys
        import bfc.training.runner as runner
        seen = []
        init = runner.Runner.__init__
        def recording(self, *args, **kwargs):
            seen.append(gc.isenabled())  # the env, the workers and the evaluator are made here
            init(self, *args, **kwargs)
        runner.Runner.__init__ = recording
        sys.argv = ["train.py", "env.num_envs=16", "collector.frames_per_batch=512", "collector.total_frames=512",
                    "eval.num_starts=4", "eval.seconds=0.5", "eval.hold_seconds=0.25", "logger.progress=false",
                    "hydra.run.dir={tmp_path}"]
        gc.disable()  # as train.py's first lines leave it when it runs as a script
        try:
            runpy.run_path("train.py", run_name="__main__")
        except SystemExit as e:
            assert not e.code, e.code
        print(seen, gc.isenabled(), gc.get_freeze_count() > 0)
        """
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.strip().splitlines()[-1] == "[True] True True"
