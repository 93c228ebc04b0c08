"""What bfc adds to Hydra's sweeps (`python train.py -m ...`, any launcher): every job records its
outcome in its run directory (`status.json`), a failed job is reported with its run directory
while the others go on, the sweep ends with one report (`sweep.json` in the sweep directory), and
a sweep resumes by running the same command again with the same `hydra.sweep.dir`: a finished
job returns at once, an unfinished one (killed, failed, interrupted) continues from its last
checkpoint (the Runner resumes any run directory that holds one). docs/training.md, "Sweeps".
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from pathlib import Path

from hydra.experimental.callback import Callback

from bfc.imports import release_garbage_collection

STATUS = "status.json"


def write_status(run_dir, status: str, **info) -> None:
    """Record a job's outcome in its run directory (atomically: write, then rename)."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    tmp = run_dir / (STATUS + ".tmp")
    tmp.write_text(json.dumps({"status": status, "unix_seconds": round(time.time(), 2), **info}, indent=1))
    tmp.replace(run_dir / STATUS)


def read_runs(sweep_dir) -> list[dict]:
    """Every job below `sweep_dir` (a directory with a status.json or Hydra's .hydra), with its outcome: finished
    (summary.json), failed, interrupted or paused (its status.json says so: checkpoint.pause_at_frames),
    or unfinished (started and stopped without a word: killed)."""
    rows = []
    marks = [*Path(sweep_dir).rglob(STATUS), *Path(sweep_dir).rglob(".hydra")]  # Hydra's own record of a job
    for run_dir in sorted({m.parent for m in marks} - {Path(sweep_dir)}):
        status_file = run_dir / STATUS
        status = json.loads(status_file.read_text()) if status_file.is_file() else {}
        state = status.get("status", "unfinished")
        summary = run_dir / "summary.json"
        # a paused run's summary is not the end: resumed and then killed, it is unfinished
        ended = summary.is_file() and not json.loads(summary.read_text()).get("paused")
        if ended and state in ("finished", "unfinished", "running"):
            state = "finished"
        elif state == "running":
            state = "unfinished"
        rows.append({"run_dir": str(run_dir), "status": state, **{k: v for k, v in status.items() if k != "status"}})
    return rows


class SweepReport(Callback):
    """Hydra callback (conf/config.yaml): at the end of a multirun, print and save what became of
    every job, and exit with status 1 if any did not finish."""

    def on_multirun_start(self, config, **kwargs) -> None:
        release_garbage_collection()  # train.py held it while importing; a sweep's process lives as long as the sweep

    def on_multirun_end(self, config, **kwargs) -> None:
        sweep_dir = Path(str(config.hydra.sweep.dir))
        rows = read_runs(sweep_dir)
        (sweep_dir / "sweep.json").write_text(json.dumps(rows, indent=1))
        done = [r for r in rows if r["status"] == "finished"]
        print(f"sweep {sweep_dir}: {len(done)} of {len(rows)} jobs finished", file=sys.stderr)
        for r in rows:
            if r["status"] != "finished":
                why = f": {r['error']}" if r.get("error") else ""
                print(f"  {r['status']}: {r['run_dir']}{why}", file=sys.stderr)
        if len(done) < len(rows):  # paused jobs too: a sweep run in stages ends with status 1 until its last
            print(f"  to resume: run the same command again with hydra.sweep.dir={sweep_dir}", file=sys.stderr)
            sys.stdout.flush()
            sys.stderr.flush()
            os._exit(1)  # Hydra has finished with every job: nothing is left to clean up


def objective(summary: dict, name: str) -> float:
    """The number a sweeper optimises (`sweep_objective`): the final or best validation success
    rate, or the seconds of training to the paper's 0.905 (NaN if never reached: such a trial
    fails, as a sweeper counts a NaN)."""
    if name == "final_success_rate":
        value = summary["final_success_rate"]
    elif name == "best_success_rate":
        value = summary["best_success_rate"]
    else:  # seconds_to_0.905
        reached = summary["first_reached_0.905"]
        value = reached["wall_seconds"] if reached else None
    return math.nan if value is None else float(value)
