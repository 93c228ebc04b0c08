"""Issue-12 targets for trained policies: every robustness suite on the test starts, for the final
policy (`policy_last.pt`) of each run, plus the last three in-training evaluations of each run;
with `--hardware`, issue 29's instead: the rows of `evaluate.py suite=hardware` (latency, the
estimator, the throw) and the protocol flown without latency.

    python bench/robust_targets.py outputs/bench/robust/seed0 outputs/bench/robust/seed1 ... \
        [--policy pretrained/policy.pt] [--json out.json] [--hardware] [--seed 1 (validation starts)]

A run directory is one `train.py` run (policy_last.pt, summary.json); `--policy` adds single
policy files (e.g. the shipped one). Prints a Markdown table (success rate, hover error) and the
targets each policy meets. Flies 100 test starts (seed 0) per suite: about 10 s per suite per
policy on 2 cores. The flights are deterministic; the wall-clock is not.
"""

from __future__ import annotations

import argparse
import json
import platform
import time
from pathlib import Path

from bfc.evaluation.protocol import TEST_SEED
from bfc.evaluation.suites import CONDITIONS, HARDWARE, robust_results

NOMINAL = ("protocol", "harsh", "any", "ground")
# suite -> minimum success rate (issue 12); hover-error bounds in metres
MIN_SUCCESS = {"protocol": 1.0, "ground": 1.0, "harsh": 0.99, "any": 0.97}
MISMATCH_MIN_SUCCESS = 0.99
HOVER_NOMINAL, HOVER_MISMATCH = 0.010, 0.015


# row -> (minimum success rate, largest hover error in metres or None: not judged)
ROBUST_TARGETS = {
    name: (
        MIN_SUCCESS.get(name, MISMATCH_MIN_SUCCESS),
        None if name in ("harsh", "any", "ground") else HOVER_NOMINAL if name == "protocol" else HOVER_MISMATCH,
    )
    for name in CONDITIONS
}
HARDWARE_TARGETS = {  # issue 29
    "protocol": (1.0, 0.010),
    "observation latency 30 ms": (0.99, 0.010),
    "observation latency 50 ms": (0.95, 0.020),
    "estimator noise, gyro bias": (0.99, 0.010),
    "throw 5 m/s, any attitude": (0.97, None),
}


def targets_met(results: dict, label: str, targets: dict) -> list[str]:
    """The targets (row -> (floor, bound)) `label` misses (empty: all met)."""
    missed = []
    for name, (floor, bound) in targets.items():
        s = results[name][label]
        if s["success_rate"] < floor:
            missed.append(f"{name} success {s['success_rate']:.2f} < {floor}")
        e = s["hover_error_m"]
        if bound is not None and (e is None or e > bound):
            missed.append(f"{name} hover {'n/a' if e is None else f'{100 * e:.1f} cm'} > {100 * bound:.1f} cm")
    return missed


def last_evaluations(run: Path, k: int = 3) -> list[float]:
    summary = json.loads((run / "summary.json").read_text())
    return [round(h["eval/success_rate"], 3) for h in summary["history"][-k:]]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("runs", nargs="*", type=Path, help="train.py run directories")
    p.add_argument("--policy", nargs="*", default=[], help="extra policy files")
    every_suite = ", ".join(CONDITIONS).replace("%", "%%")  # argparse formats help with %
    p.add_argument("--suites", nargs="*", default=None, help=f"default: all of {every_suite}")
    p.add_argument("--hardware", action="store_true", help="the protocol and suite=hardware's rows, issue 29's targets")
    p.add_argument("--seed", type=int, default=TEST_SEED, help="the starts' seed (0: the test starts)")
    p.add_argument("--num-starts", type=int, default=100)
    p.add_argument("--json", type=Path, help="also write the results here")
    args = p.parse_args()
    controllers = {f"{run.name} last": str(run / "policy_last.pt") for run in args.runs}
    controllers.update({Path(path).parent.name + "/" + Path(path).name: str(path) for path in args.policy})
    if not controllers:
        p.error("give run directories and/or --policy files")
    rows = CONDITIONS if not args.hardware else {"protocol": None, **HARDWARE}
    suites = list(rows) if args.suites is None else args.suites
    t0 = time.perf_counter()
    results = robust_results(controllers, suites, args.num_starts, args.seed)
    elapsed = time.perf_counter() - t0
    print(
        f"# {platform.machine()}, {platform.python_version()}: {len(controllers)} policies x {len(suites)} suites "
        f"x {args.num_starts} starts (seed {args.seed}) in {elapsed:.0f} s"
    )
    labels = list(controllers)
    print("| suite | " + " | ".join(labels) + " |")
    print("|---|" + "---|" * len(labels))
    for name, row in results.items():
        cells = []
        for label in labels:
            s, e = row[label], row[label]["hover_error_m"]
            cells.append(f"{s['success_rate']:.2f}, " + ("n/a" if e is None else f"{100 * e:.1f} cm"))
        print(f"| {name} | " + " | ".join(cells) + " |")
    for run in args.runs:
        print(f"{run.name}: last three in-training evaluations {last_evaluations(run)}")
    for label in labels:
        targets = HARDWARE_TARGETS if args.hardware else ROBUST_TARGETS
        missed = targets_met(results, label, targets) if set(suites) == set(rows) else ["(not every suite flown)"]
        print(f"{label}: " + ("every target met" if not missed else "misses " + "; ".join(missed)))
    if args.json:
        args.json.write_text(json.dumps(results, indent=1))


if __name__ == "__main__":
    main()
