"""How a run ends when something kills it: a trainer killed with SIGKILL leaves no collector
worker behind, a killed worker ends the trainer with one line and a checkpoint that resumes bit
for bit, SIGTERM is a preemption (a checkpoint, status 143, a bit-identical resume), and none of
them leaves a shared-memory segment or a multiprocessing socket behind. Real `train.py`
processes, real signals."""

import os
import resource
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from bfc import lifetime
from bfc.training import train
from tests.process_helpers import alive, children, descendants, leftovers, name

from .helpers import ROOT, TINY, as_from_a_shell, assert_same_checkpoint, compose_cfg, overriding

# one collector worker (the default's layout), frame-counted schedules pinned so that a shorter
# or interrupted run follows the same ones
ASYNC = overriding(
    TINY,
    "collector.workers=1",
    "eval.interval_frames=1000000",
    "checkpoint.interval_frames=1000000",  # the only checkpoints: the signal's and the last
    "optim.anneal_lr=false",
    "env.episode_seconds=0.2",
    "seed=5",
    "collector.total_frames=4194304",  # a run that is killed long before it ends
)


def wait_for(predicate, seconds: float, what: str):
    deadline = time.time() + seconds
    while time.time() < deadline:
        value = predicate()
        if value:
            return value
        time.sleep(0.1)
    pytest.fail(f"{what} did not happen within {seconds} s")


def no_core_files() -> None:
    resource.setrlimit(resource.RLIMIT_CORE, (0, 0))  # a worker the test crashes writes no core file


def start(args: list[str]) -> subprocess.Popen:
    return subprocess.Popen(
        [sys.executable, "train.py", *args],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=no_core_files,
    )


def worker_of(process: subprocess.Popen, child: str = "bfc-collector-0") -> int:
    """The pid of the run's child process named `child` (bfc-collector-k, bfc-evaluator)."""

    def started():
        if process.poll() is not None:
            pytest.fail(
                f"train.py ended ({process.returncode}) before its worker started: {process.stderr.read()[-3000:]}"
            )
        return [p for p in children(process.pid) if name(p) == child]

    return wait_for(started, 120, f"the start of {child}")[0]


pytestmark = pytest.mark.skipif(not sys.platform.startswith("linux"), reason="reads /proc")


WHERE = {
    "run": ["hydra.run.dir={dir}"],
    "sweep": ["-m", "hydra.sweep.dir={dir}"],  # Hydra's basic launcher: the job in the sweep's process
    "joblib sweep": ["-m", "hydra/launcher=joblib", "hydra.sweep.dir={dir}"],  # the job in a loky worker
}


@pytest.mark.parametrize("how", list(WHERE))
def test_nothing_a_run_started_outlives_it_killed_with_sigkill(tmp_path, how):
    if how == "joblib sweep":
        pytest.importorskip("hydra_plugins.hydra_joblib_launcher")
    before = leftovers()
    process = start([*(a.format(dir=tmp_path) for a in WHERE[how]), *ASYNC])

    def collectors():
        if process.poll() is not None:
            pytest.fail(f"train.py ended ({process.returncode}): {process.stderr.read()[-3000:]}")
        named = {name(p) for p in descendants(process.pid)}  # named in ps and top
        return {"bfc-collector-0", "bfc-evaluator"} <= named

    wait_for(collectors, 120, "the start of the collector worker and the background evaluator")
    wait_for(lambda: list(tmp_path.rglob("tb/events*")), 120, "training")
    tree = descendants(process.pid)
    process.kill()
    process.wait(timeout=30)
    wait_for(lambda: not any(alive(p) for p in tree), 10, "the exit of every process the run started")
    wait_for(lambda: leftovers() <= before, 10, "the removal of the launcher's shared memory")


def test_a_killed_worker_ends_the_run_with_one_line_and_its_checkpoint_resumes_bit_for_bit(tmp_path):
    overrides = overriding(
        ASYNC, "collector.total_frames=6144", "checkpoint.interval_frames=2048", "jd.decay_frames=6144"
    )
    full, part = tmp_path / "full", tmp_path / "part"
    train(compose_cfg(overrides), full)
    before = leftovers()
    process = start([f"hydra.run.dir={part}", *overrides])
    worker = worker_of(process)
    wait_for(lambda: (part / "checkpoints" / "last.pt").exists(), 120, "the first checkpoint")
    os.kill(worker, signal.SIGKILL)
    _, err = process.communicate(timeout=60)
    lines = [line for line in err.strip().splitlines() if "[INFO]" not in line]
    assert process.returncode == lifetime.FAILED, err[-3000:]
    assert len(lines) == 1 and "Traceback" not in err, err[-3000:]
    assert lines[0].startswith(f"error: collector worker 0 (pid {worker}) died: killed by SIGKILL; ")
    assert f"resume={part}" in lines[0]
    assert leftovers() <= before
    resumed = subprocess.run(
        [sys.executable, "train.py", f"resume={part}"], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    a = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert a["frames"] == b["frames"] == 6144 and b["resumed_from"] and b["resumed_from"][0] < 6144
    assert_same_checkpoint(a, b)


def test_sigterm_is_a_preemption_a_checkpoint_status_143_and_a_bit_identical_resume(tmp_path):
    overrides = overriding(ASYNC, "collector.total_frames=16384", "jd.decay_frames=16384")
    full, part = tmp_path / "full", tmp_path / "part"
    train(compose_cfg(overrides), full)
    before = leftovers()
    process = start([f"hydra.run.dir={part}", *overrides])
    worker = worker_of(process)
    wait_for(lambda: list(part.glob("tb/events*")), 120, "training")
    # as a scheduler or `pkill` does: the trainer and its worker both get SIGTERM
    for pid in (worker, process.pid):
        os.kill(pid, signal.SIGTERM)
    _, err = process.communicate(timeout=60)
    assert process.returncode == lifetime.PREEMPTED, err[-3000:]
    last = err.strip().splitlines()[-1]
    assert last.startswith("preempted (SIGTERM): checkpoint written at ") and f"resume={part}" in last
    assert "Traceback" not in err
    stopped = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert 0 < stopped["frames"] < 16384 and not (part / "summary.json").exists()
    assert not alive(worker) and leftovers() <= before
    resumed = subprocess.run(
        [sys.executable, "train.py", f"resume={part}"], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert resumed.returncode == 0, resumed.stderr[-3000:]
    a = torch.load(full / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(part / "checkpoints" / "last.pt", weights_only=True)
    assert a["frames"] == b["frames"] == 16384 and b["resumed_from"] == [stopped["frames"]]
    assert_same_checkpoint(a, b)


def test_sigterm_is_left_to_a_handler_that_is_already_there():
    """submitit keeps SIGTERM for a SLURM job's requeue: bfc does not take it over."""
    mine = signal.signal(signal.SIGTERM, lambda *a: None)
    try:
        with lifetime.SigtermGuard() as guard:
            assert signal.getsignal(signal.SIGTERM) is not guard._handle
    finally:
        signal.signal(signal.SIGTERM, mine)
    with lifetime.SigtermGuard() as guard:
        os.kill(os.getpid(), signal.SIGTERM)
        wait_for(lambda: guard.requested, 5, "SIGTERM's arrival")
    assert signal.getsignal(signal.SIGTERM) is signal.SIG_DFL


def test_death_causes_are_named():
    assert lifetime.death_cause(-9) == "killed by SIGKILL"
    assert lifetime.death_cause(-11) == "killed by SIGSEGV"
    assert lifetime.death_cause(3) == "exited with status 3"


MIDDLE = """
import multiprocessing, sys, time
from bfc.lifetime import bind_to_parent

def child(parent):
    bind_to_parent(parent, "bfc-test-child")
    time.sleep(600)  # no pipe to notice the parent's death by: only bfc.lifetime can end it

if __name__ == "__main__":
    import os
    p = multiprocessing.get_context("fork").Process(target=child, args=(os.getpid(),))
    p.start()
    print(p.pid, flush=True)
    time.sleep(600)
"""


def test_bind_to_parent_ends_a_busy_worker_when_its_parent_is_killed():
    middle = subprocess.Popen([sys.executable, "-c", MIDDLE], cwd=ROOT, stdout=subprocess.PIPE, text=True)
    child = int(middle.stdout.readline())
    named = lambda: Path(f"/proc/{child}/comm").read_text().strip() == "bfc-test-child"  # noqa: E731
    wait_for(named, 30, "the child's binding")
    middle.kill()
    middle.wait(timeout=30)
    try:
        wait_for(lambda: not alive(child), 5, "the child's exit")
    finally:
        if alive(child):
            os.kill(child, signal.SIGKILL)


@pytest.mark.parametrize("sig", [signal.SIGINT, signal.SIGKILL], ids=["ctrl-c", "sigkill"])
@pytest.mark.parametrize("sim", ["mujoco", "rotorpy"])
def test_stopping_evaluate_leaves_no_process_and_no_shared_memory(tmp_path, sim, sig):
    if sim == "rotorpy":
        pytest.importorskip("rotorpy")
    before = leftovers()
    shipped = ROOT / "pretrained" / "policy.pt"
    args = [
        "evaluate.py",
        f"policy={shipped}",
        "suite=robust",
        f"sim={sim}",
        "baselines=[]",
        f"hydra.run.dir={tmp_path}",
    ]
    process = subprocess.Popen(
        [sys.executable, *args],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
        preexec_fn=as_from_a_shell,  # SIGINT at its default, as typed in a shell
    )
    wait_for(lambda: (tmp_path / ".hydra" / "config.yaml").exists(), 60, "evaluate.py's start")
    time.sleep(4)  # in the imports or the flights
    assert process.poll() is None, process.stderr.read()[-3000:]
    spawned = children(process.pid)
    process.send_signal(sig)
    _, err = process.communicate(timeout=60)
    if sig == signal.SIGINT:
        assert process.returncode == lifetime.INTERRUPTED and "Traceback" not in err, err[-3000:]
        assert err.strip().splitlines()[-1].startswith("interrupted:")
    wait_for(lambda: not any(alive(p) for p in spawned), 10, "the exit of what evaluate.py started")
    assert leftovers() <= before


@pytest.mark.parametrize(
    ("child", "called"), [("bfc-collector-0", "collector worker 0"), ("bfc-evaluator", "the background evaluator")]
)
def test_a_worker_that_crashes_is_named_with_its_signal(tmp_path, child, called):
    """A segfault in MuJoCo's C code reads as SIGSEGV: the one line names it and the process."""
    process = start([f"hydra.run.dir={tmp_path}", *ASYNC])
    worker = worker_of(process, child)
    wait_for(lambda: list(tmp_path.glob("tb/events*")), 120, "training")
    os.kill(worker, signal.SIGSEGV)
    _, err = process.communicate(timeout=120)
    lines = [line for line in err.strip().splitlines() if "[INFO]" not in line]
    assert process.returncode == lifetime.FAILED and len(lines) == 1, err[-3000:]
    assert f"error: {called} (pid {worker}) died: killed by SIGSEGV; " in lines[0]
