"""Sweeps beyond one process: a job that fails is reported and the others finish, a killed sweep
resumes by running again, and Hydra's Ray (on a real local cluster), submitit and Optuna plugins
run bfc's jobs. Each test runs tiny trainings through the real `train.py -m`."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from tests.training.helpers import as_from_a_shell

ROOT = Path(__file__).resolve().parents[1]
# tiny jobs, one thread each, collected in the learner's process (two jobs share the two cores)
TINY = [
    "env.num_envs=16",
    "collector.frames_per_batch=512",
    "collector.total_frames=1024",
    "collector.workers=0",
    "loss.num_minibatches=2",
    "eval.num_starts=2",
    "eval.seconds=0.5",
    "eval.hold_seconds=0.2",
    "eval.interval_frames=512",
    "checkpoint.interval_frames=512",
    "logger.progress=false",
    "env.num_threads=1",
    "torch_threads=1",
]


def sweep(*args, timeout=600, cwd=ROOT) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "train.py", "-m", *args], cwd=cwd, capture_output=True, text=True, timeout=timeout
    )


def runs(sweep_dir: Path) -> dict[str, dict]:
    return {r["run_dir"]: r for r in json.loads((sweep_dir / "sweep.json").read_text())}


def test_a_failing_job_is_reported_with_its_run_directory_and_the_others_finish(tmp_path):
    r = sweep(*TINY, "+ablation=jd,ppo", "loss.gamma=0.99,1.5", f"hydra.sweep.dir={tmp_path}")
    assert r.returncode == 1, r.stderr[-3000:]
    jobs = runs(tmp_path)
    failed = [d for d, j in jobs.items() if j["status"] == "failed"]
    finished = [d for d, j in jobs.items() if j["status"] == "finished"]
    assert len(jobs) == 4 and len(failed) == 2 and len(finished) == 2
    for d in failed:
        assert "loss.gamma must be in (0, 1], got 1.5" in jobs[d]["error"]
        assert f"error: job {d}: loss.gamma must be" in r.stderr
        assert f"  failed: {d}" in r.stderr
    for d in finished:
        assert (Path(d) / "policy.pt").is_file() and json.loads((Path(d) / "summary.json").read_text())[
            "frames"
        ] == 1024
    assert "Traceback" not in r.stderr


def test_a_killed_sweep_resumes_by_running_again(tmp_path):
    """Kill -9 a sequential sweep while its second job trains; the same command again returns the
    finished job at once and continues the killed one from its checkpoint to the end."""
    longer = [*TINY[:2], "collector.total_frames=8192", *TINY[3:]]
    args = [*longer, "seed=0,1", f"hydra.sweep.dir={tmp_path}"]
    process = subprocess.Popen(
        [sys.executable, "train.py", "-m", *args], cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE
    )
    second = None
    deadline = time.time() + 300
    while time.time() < deadline:
        found = [p for p in tmp_path.glob("*/seed1_1/checkpoints/last.pt")]
        if found:
            second = found[0].parents[1]
            break
        time.sleep(0.2)
    assert second is not None, "the second job never checkpointed"
    process.send_signal(signal.SIGKILL)
    process.wait(timeout=30)
    first = next(tmp_path.glob("*/seed0_0"))
    finished_at = (first / "policy_last.pt").stat().st_mtime
    assert not (second / "summary.json").exists()
    r = sweep(*args)
    assert r.returncode == 0, r.stderr[-3000:]
    assert (first / "policy_last.pt").stat().st_mtime == finished_at  # nothing trained twice
    summary = json.loads((second / "summary.json").read_text())
    assert summary["frames"] == 8192 and summary["resumed_from"] and summary["resumed_from"][0] >= 512
    assert all(j["status"] == "finished" for j in runs(tmp_path).values())


def test_ctrl_c_stops_a_sweep_and_leaves_its_finished_runs_whole(tmp_path):
    """A sequential sweep of a short and a long job, interrupted (SIGINT, as Ctrl-C sends) while
    the long one trains: one line, exit status 130, the short job's run whole."""
    args = [*TINY, "collector.total_frames=1024,1048576", f"hydra.sweep.dir={tmp_path}"]
    process = subprocess.Popen(
        [sys.executable, "train.py", "-m", *args],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        env={**os.environ, "PYTHONFAULTHANDLER": "1"},  # SIGABRT dumps every thread's stack
        preexec_fn=as_from_a_shell,
    )
    deadline = time.time() + 300
    while time.time() < deadline and not list(tmp_path.glob("*/seed0_1/checkpoints/last.pt")):
        time.sleep(0.2)
    process.send_signal(signal.SIGINT)
    try:
        _, err = process.communicate(timeout=120)
    except subprocess.TimeoutExpired:  # a hang: say where each thread is
        process.send_signal(signal.SIGABRT)
        _, err = process.communicate(timeout=60)
        pytest.fail(f"the sweep did not stop within 120 s of SIGINT; its threads:\n{err[-8000:]}")
    assert process.returncode == 130, err[-3000:]
    assert err.strip().splitlines()[-1].startswith("interrupted: every finished run is complete")
    assert "Traceback" not in err
    first, second = next(tmp_path.glob("*/seed0_0")), next(tmp_path.glob("*/seed0_1"))
    assert json.loads((first / "summary.json").read_text())["frames"] == 1024
    assert json.loads((second / "status.json").read_text())["status"] == "interrupted"


def test_a_launcher_or_a_cluster_that_is_not_there_is_one_line_and_no_job(tmp_path):
    r = sweep("hydra/launcher=ray", "hydra.launcher.ray.init.address=127.0.0.1:9", "+ablation=jd,ppo")
    assert r.returncode == 2 and r.stderr.strip().splitlines() == [r.stderr.strip()]
    assert "no Ray cluster answers at hydra.launcher.ray.init.address=127.0.0.1:9" in r.stderr
    from bfc import cli

    original = dict(cli.PLUGINS["hydra/launcher"])
    try:
        cli.PLUGINS["hydra/launcher"]["joblib"] = ("hydra_plugins.no_such_launcher", "joblib")
        with pytest.raises(
            ValueError, match=r'hydra/launcher=joblib needs the joblib extra: pip install -e "\.\[joblib\]"'
        ):
            cli.check_plugins(["hydra/launcher=joblib"])
    finally:
        cli.PLUGINS["hydra/launcher"].update(original)
    r = sweep("+ablation=jd,ppo", "+loss.clipp=0.1,0.2", f"hydra.sweep.dir={tmp_path}")
    assert r.returncode == 2 and "unknown config key 'loss.clipp'" in r.stderr and not any(tmp_path.iterdir())


def test_submitit_local_runs_the_jobs_and_its_preemption_hook_resumes_a_run(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_submitit_launcher")
    longer = [*TINY[:2], "collector.total_frames=16384", *TINY[3:]]
    process = subprocess.Popen(
        [
            sys.executable,
            "train.py",
            "-m",
            "hydra/launcher=submitit_local",
            *longer,
            "seed=0,1",
            f"hydra.sweep.dir={tmp_path}",
        ],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    job, deadline = None, time.time() + 300
    while time.time() < deadline and job is None:
        for status in tmp_path.glob("*/seed1_1/status.json"):
            if (status.parent / "checkpoints" / "last.pt").exists():
                job = status.parent
        time.sleep(0.2)
    assert job is not None, "the job never checkpointed"
    pid = json.loads((job / "status.json").read_text())["pid"]
    os.kill(pid, signal.SIGUSR2)  # what SLURM sends before a preemption or the time limit
    _, err = process.communicate(timeout=600)
    assert process.returncode == 0, err[-3000:]
    summary = json.loads((job / "summary.json").read_text())
    assert summary["frames"] == 16384 and len(summary["resumed_from"]) == 1  # requeued once, resumed
    assert all(j["status"] == "finished" for j in runs(tmp_path).values()) and len(runs(tmp_path)) == 2


def test_an_optuna_search_over_documented_keys_runs_and_reports_its_best(tmp_path):
    pytest.importorskip("hydra_plugins.hydra_optuna_sweeper")
    r = sweep(
        "hydra/sweeper=optuna",
        "hydra.sweeper.n_trials=3",
        "hydra.sweeper.n_jobs=1",
        "hydra.sweeper.direction=maximize",
        "hydra.sweeper.sampler.seed=0",
        "optim.lr=interval(0.0005,0.003)",
        "loss.clip_epsilon=choice(0.1,0.2)",
        "sweep_objective=best_success_rate",
        *TINY,
        f"hydra.sweep.dir={tmp_path}",
    )
    assert r.returncode == 0, r.stderr[-3000:]
    best = (tmp_path / "optimization_results.yaml").read_text()
    assert "best_params" in best and "optim.lr" in best and "best_value" in best
    assert len(runs(tmp_path)) == 3


RAY_SCRIPT = """
set -e
ip link set lo up
export RAY_ADDRESS=
ray start --head --port={port} --num-cpus=2 --include-dashboard=false --disable-usage-stats > {out}/ray.log 2>&1
trap 'ray stop --force > /dev/null 2>&1' EXIT
{python} train.py -m hydra/launcher=ray hydra.launcher.ray.init.address=127.0.0.1:{port} {overrides} \
  > {out}/sweep.out 2> {out}/sweep.err &
sweep=$!
# kill -9 one job's process once it has a checkpoint: Ray runs the task again, which resumes it
for i in $(seq 600); do
  if [ -f {sweep_dir}/jd_css/seed0_1/checkpoints/last.pt ] && [ -f {sweep_dir}/jd_css/seed0_1/status.json ]; then
    kill -9 $({python} -c "import json; print(json.load(open('{sweep_dir}/jd_css/seed0_1/status.json'))['pid'])")
    echo killed > {out}/killed
    break
  fi
  sleep 0.2
done
wait $sweep
echo $? > {out}/sweep.rc
{python} evaluate.py suite=paper runs={sweep_dir} eval.num_starts=2 eval.seconds=0.5 eval.hold_seconds=0.2 \
  hydra.run.dir={out}/report > {out}/report.out 2>&1
echo $? > {out}/report.rc
"""


def test_a_sweep_runs_on_a_local_ray_cluster_and_survives_a_killed_job(tmp_path):
    """A real single-node Ray cluster on 127.0.0.1 (its own network namespace, its own port),
    Hydra's Ray launcher joining it, one job's process killed mid-run; the report of the sweep."""
    pytest.importorskip("hydra_plugins.hydra_ray_launcher")
    unshare = shutil.which("unshare")
    if unshare is None:
        pytest.skip("needs util-linux's unshare for a private network namespace")
    net = [unshare, "--net"] if os.geteuid() == 0 else [unshare, "--map-root-user", "--net"]
    if subprocess.run([*net, "true"], capture_output=True).returncode != 0:
        pytest.skip("cannot make a network namespace here (unshare --net refused)")
    longer = [*TINY[:2], "collector.total_frames=4096", *TINY[3:]]
    sweep_dir = tmp_path / "sweep"
    script = RAY_SCRIPT.format(
        port=6391,
        out=tmp_path,
        python=sys.executable,
        sweep_dir=sweep_dir,
        overrides=" ".join(["+ablation=jd,jd_css", *longer, f"hydra.sweep.dir={sweep_dir}"]),
    )
    env = {
        **os.environ,
        "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
        "RAY_DISABLE_DOCKER_CPU_WARNING": "1",
    }
    subprocess.run([*net, "bash", "-c", script], cwd=ROOT, env=env, timeout=900, check=False)
    err = (tmp_path / "sweep.err").read_text() if (tmp_path / "sweep.err").exists() else ""
    assert (tmp_path / "sweep.rc").read_text().strip() == "0", err[-3000:]
    assert (tmp_path / "killed").exists()
    jobs = runs(sweep_dir)
    assert len(jobs) == 2 and all(j["status"] == "finished" for j in jobs.values())
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    for run_dir in map(Path, jobs):
        assert (run_dir / "policy.pt").is_file()
        ea = EventAccumulator(str(run_dir / "tb"))
        ea.Reload()
        assert "eval/success_rate" in ea.Tags()["scalars"]
    killed = json.loads((sweep_dir / "jd_css" / "seed0_1" / "summary.json").read_text())
    assert killed["frames"] == 4096 and killed["resumed_from"]  # Ray ran it again: it resumed
    assert (tmp_path / "report.rc").read_text().strip() == "0", (tmp_path / "report.out").read_text()[-2000:]
    report = (tmp_path / "report" / "report.md").read_text()
    assert "| jd |" in report and "| jd_css |" in report


def test_a_paused_job_is_reported_paused_and_a_resumed_then_killed_one_unfinished(tmp_path):
    """status.json and summary.json together: paused (checkpoint.pause_at_frames) stays paused; a
    paused job resumed and killed (status running, its old paused summary) is unfinished; a
    summary that is not paused means finished."""
    from bfc.sweeps import read_runs

    cases = {"a": ("paused", True), "b": ("running", True), "c": ("running", False), "d": ("finished", False)}
    for name, (status, paused) in cases.items():
        (tmp_path / name).mkdir()
        (tmp_path / name / "status.json").write_text(json.dumps({"status": status}))
        (tmp_path / name / "summary.json").write_text(json.dumps({"frames": 1, "paused": paused}))
    states = {Path(r["run_dir"]).name: r["status"] for r in read_runs(tmp_path)}
    assert states == {"a": "paused", "b": "unfinished", "c": "finished", "d": "finished"}


def test_joblib_idle_workers_wait_2_s_for_a_job_unless_the_command_line_says_otherwise():
    """An idle loky worker would outlive a killed sweep by joblib's 300 s (tests/training/test_lifetime.py)."""
    from bfc.cli import with_launcher_defaults

    args = ["-m", "hydra/launcher=joblib", "seed=0,1"]
    assert with_launcher_defaults(args) == [*args, "+hydra.launcher.idle_worker_timeout=2"]
    mine = [*args, "+hydra.launcher.idle_worker_timeout=30"]
    assert with_launcher_defaults(mine) == mine
    assert with_launcher_defaults(["-m", "seed=0,1"]) == ["-m", "seed=0,1"]
