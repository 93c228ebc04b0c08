"""A soak: the default training run for an hour, its processes watched from outside.

    python bench/soak.py [--minutes 60] [--interval 30] [--warmup 5] [--end sigterm|sigkill] [-- overrides]

Starts `python train.py` (the default, with collector.total_frames large enough that it never
ends by itself: JD's decay and the learning rate's anneal follow that total, so they barely move;
a soak watches the processes, not the learning), and every --interval seconds prints, for the
trainer and each collector worker, the resident memory (VmRSS), open file descriptors and
threads, with the machine's shared-memory segments (/dev/shm) and multiprocessing's sockets
(pymp-* in the temporary directory). After
--minutes it ends the run as a scheduler would (SIGTERM: a checkpoint, exit status 143) or as
the OOM killer would (SIGKILL), and checks that no process of the run is left and nothing new is
left in /dev/shm or the temporary directory. The closing lines give each process's growth after
--warmup minutes (the bound docs/training.md states). Run nothing else beside it.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.process_helpers: what the lifetime tests read from /proc
from tests.process_helpers import alive, children, leftovers  # noqa: E402

NEVER_ENDS = "collector.total_frames=10000000000"


def sample(pid: int) -> dict | None:
    """A process's resident memory (MiB), open descriptors and threads, from /proc."""
    try:
        status = dict(
            line.split(":", 1) for line in Path(f"/proc/{pid}/status").read_text().splitlines() if ":" in line
        )
        fds = len(os.listdir(f"/proc/{pid}/fd"))
    except OSError:
        return None
    return {"rss_mib": int(status["VmRSS"].split()[0]) / 1024, "fds": fds, "threads": int(status["Threads"])}


def main() -> int:
    argv = sys.argv[1:]
    extra = argv[argv.index("--") + 1 :] if "--" in argv else []
    argv = argv[: argv.index("--")] if "--" in argv else argv
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--minutes", type=float, default=60.0)
    parser.add_argument("--interval", type=float, default=30.0, help="seconds between samples")
    parser.add_argument("--warmup", type=float, default=5.0, help="minutes before growth is counted")
    parser.add_argument("--end", choices=("sigterm", "sigkill"), default="sigterm")
    parser.add_argument("--out", default="outputs/bench/soak", help="run directory and soak.json")
    args = parser.parse_args(argv)

    out = ROOT / args.out
    before = leftovers()
    launched = time.time()
    trainer = subprocess.Popen(
        [sys.executable, "train.py", f"hydra.run.dir={out}", "logger.progress=false", NEVER_ENDS, *extra],
        cwd=ROOT,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    rows, seen = [], set()
    print("| minute | process | RSS MiB | fds | threads | /dev/shm + pymp |")
    print("|---|---|---|---|---|---|")
    try:
        while time.time() - launched < args.minutes * 60:
            time.sleep(min(args.interval, max(0.0, args.minutes * 60 - (time.time() - launched))))
            if trainer.poll() is not None:
                print(f"train.py ended early ({trainer.returncode}): {trainer.stderr.read()[-2000:]}")
                return 1
            minute = (time.time() - launched) / 60
            extra_files = len(leftovers() - before)
            for name, pid in [("trainer", trainer.pid), *[(f"worker {p}", p) for p in children(trainer.pid)]]:
                seen.add(pid)
                s = sample(pid)
                if s is not None:
                    rows.append({"minute": round(minute, 2), "process": name, **s, "leftovers": extra_files})
                    print(
                        f"| {minute:.1f} | {name} | {s['rss_mib']:.0f} | {s['fds']} | {s['threads']} | {extra_files} |",
                        flush=True,
                    )
    finally:
        if trainer.poll() is None:
            trainer.send_signal(signal.SIGTERM if args.end == "sigterm" else signal.SIGKILL)
    _, err = trainer.communicate(timeout=300)
    deadline = time.time() + 10
    while time.time() < deadline and any(alive(p) for p in seen):
        time.sleep(0.1)
    left_alive = sorted(p for p in seen if alive(p))
    left_files = sorted(leftovers() - before)

    print()
    said = err.strip().splitlines()[-1] if err.strip() else ""
    print(f"ended with {args.end}: exit status {trainer.returncode}; {said}")
    print(f"processes of the run alive 10 s later: {left_alive or 'none'}")
    print(f"new in /dev/shm or pymp-*: {left_files or 'none'}")
    growth = {}
    for name in sorted({r["process"] for r in rows}):
        mine = [r for r in rows if r["process"] == name]
        warm = [r for r in mine if r["minute"] >= args.warmup] or mine
        first, peak, last = warm[0], max(r["rss_mib"] for r in warm), warm[-1]
        growth[name] = {
            "rss_after_warmup_mib": round(first["rss_mib"], 1),
            "rss_peak_mib": round(peak, 1),
            "rss_last_mib": round(last["rss_mib"], 1),
            "fds": sorted({r["fds"] for r in warm}),
        }
        print(
            f"{name}: RSS {first['rss_mib']:.0f} MiB at minute {first['minute']:.1f}, peak {peak:.0f}, "
            f"last {last['rss_mib']:.0f} ({last['rss_mib'] - first['rss_mib']:+.1f} MiB); "
            f"fds {min(r['fds'] for r in warm)}-{max(r['fds'] for r in warm)}"
        )
    result = {
        "minutes": args.minutes,
        "end": args.end,
        "exit_status": trainer.returncode,
        "alive_after": left_alive,
        "leftovers": left_files,
        "growth": growth,
        "samples": rows,
        "overrides": extra,
    }
    (out / "soak.json").write_text(json.dumps(result, indent=1))
    return 0 if not left_alive and not left_files else 1


if __name__ == "__main__":
    sys.exit(main())
