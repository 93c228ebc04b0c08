"""How bfc's processes end: a collector worker never outlives its trainer, a trainer never waits on
a dead worker, and SIGTERM is a preemption (a checkpoint, then a documented exit status).

A leaf module (like bfc.keys): the collectors, the training runner and the entry points use it;
it imports nothing from bfc, nor torch, so train.py can name its exceptions before torch loads.
Linux gives a worker a parent-death signal (prctl PR_SET_PDEATHSIG); a watchdog thread that polls
the parent's pid, as PyTorch's DataLoader workers do, covers the rest.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import signal
import sys
import threading
import time

# Exit statuses of train.py and evaluate.py (docs/training.md, "Ending a run")
FAILED = 1  # a run that could not go on (a collector worker died): its last checkpoint resumes it
BAD_INPUT = 2  # an unknown key, a value out of range, a missing file: one `error:` line
INTERRUPTED = 130  # Ctrl-C (128 + SIGINT)
PREEMPTED = 128 + signal.SIGTERM  # 143: SIGTERM, after a checkpoint was written

WATCHDOG_SECONDS = 0.5  # how often a worker looks for its parent where no parent-death signal exists
_PR_SET_PDEATHSIG, _PR_SET_NAME = 1, 15


class WorkerDied(RuntimeError):
    """A collector worker ended without being asked to (killed, crashed): the run cannot go on."""


class Preempted(Exception):
    """SIGTERM reached a training run, which wrote a checkpoint at `frames` and stopped."""

    def __init__(self, frames: int):
        super().__init__(f"preempted (SIGTERM) at {frames} frames")
        self.frames = int(frames)


def death_cause(exitcode: int | None) -> str:
    """How a process ended, in words: 'killed by SIGKILL', 'exited with status 3'."""
    if exitcode is None:
        return "stopped answering"
    if exitcode < 0:
        try:
            return f"killed by {signal.Signals(-exitcode).name}"
        except ValueError:
            return f"killed by signal {-exitcode}"
    return f"exited with status {exitcode}"


def bind_to_parent(parent_pid: int, name: str) -> None:
    """In a freshly forked worker: die with the parent, whatever kills it; leave SIGINT and SIGTERM
    to the parent (a Ctrl-C or a scheduler's SIGTERM reaches the whole process group, and the
    trainer needs its workers alive to write its checkpoint, after which it stops them); show
    `name` in ps and top."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
        libc.prctl(_PR_SET_NAME, name.encode()[:15], 0, 0, 0)
    if os.getppid() != parent_pid:  # the parent died before the signal was armed
        os._exit(FAILED)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="bfc-parent-watchdog").start()


def _watch_parent(parent_pid: int) -> None:
    while os.getppid() == parent_pid:
        time.sleep(WATCHDOG_SECONDS)
    os._exit(FAILED)


SWEEP_PID = "BFC_SWEEP_PID"  # set by train.py: the process a sweep was started in
_bound_to_sweep = False


def mark_sweep_process() -> None:
    """In train.py's own process: name it, for the jobs a launcher starts in processes of its own."""
    os.environ[SWEEP_PID] = str(os.getpid())


def bind_job_to_sweep() -> None:
    """In a sweep's job: where the launcher runs it in a process the sweep's process started
    (joblib's loky workers, submitit_local), that process ends when the sweep's does, and takes its
    collector workers with it. A watchdog only (no parent-death signal: a launcher may start its
    workers from a thread that ends before them). Jobs in the sweep's own process (the basic
    launcher) or started by a cluster (Ray, SLURM) are left to it."""
    global _bound_to_sweep
    sweep = int(os.environ.get(SWEEP_PID, "0"))
    if _bound_to_sweep or not sweep or sweep == os.getpid() or os.getppid() != sweep:
        return
    threading.Thread(target=_watch_parent, args=(sweep,), daemon=True, name="bfc-sweep-watchdog").start()
    _bound_to_sweep = True


class SigtermGuard:
    """While active, SIGTERM sets `requested` instead of ending the process: the training loop
    checkpoints at the end of the update in progress and raises `Preempted`. Installed only where
    SIGTERM is still at its default and on the main thread: under submitit, whose handler keeps a
    SLURM job alive for its requeue, SIGTERM stays submitit's."""

    def __init__(self):
        self.requested = False
        self._previous = None

    def _handle(self, signum, frame) -> None:
        self.requested = True

    def __enter__(self) -> SigtermGuard:
        if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) in (
            signal.SIG_DFL,
            None,
        ):
            self._previous = signal.signal(signal.SIGTERM, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        if self._previous is not None:
            with contextlib.suppress(ValueError):
                signal.signal(signal.SIGTERM, self._previous)
            self._previous = None
