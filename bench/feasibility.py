"""Which of a row's misses could any controller have flown? For each start that none of the given
policies flies, search for motor commands that avoid the crash (bfc.evaluation.feasibility).

    python bench/feasibility.py POLICY [POLICY ...] --row "motor lag x3" [--seed 0]

Flies every policy on the row's starts (100, `--seed`: 0 the test starts, 1 the validation
starts) on its airframe, then searches each start that every policy misses: "saved" (a plan flew
it uncrashed to an upright, slow end: the crash can be avoided, the miss is the controllers'),
or "not found" (the search's budget is printed: no proof either way). Deterministic.
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from bfc.agent.policy_file import load_policy
from bfc.evaluation.feasibility import SearchBudget, search_start
from bfc.evaluation.judge import success
from bfc.evaluation.suites import condition, fly_condition


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", nargs="+", help="policy files (the first one's airframe and rate are searched)")
    p.add_argument("--row", default="motor lag x3", help="a row of suite=robust or suite=hardware")
    p.add_argument("--seed", type=int, default=0, help="the row's starts: 0 test (default), 1 validation")
    p.add_argument("--num-starts", type=int, default=100)
    p.add_argument("--population", type=int, default=SearchBudget.population)
    p.add_argument("--iterations", type=int, default=SearchBudget.iterations)
    p.add_argument("--knot-seconds", type=float, default=SearchBudget.knot_seconds)
    args = p.parse_args()
    try:
        row = condition(args.row)
    except ValueError as e:
        p.error(str(e))
    for path in args.policies:
        if not Path(path).is_file():
            p.error(f"no policy file {path!r}: give policy.pt files (train.py writes them)")
    budget = SearchBudget(population=args.population, iterations=args.iterations, knot_seconds=args.knot_seconds)
    missed = torch.ones(args.num_starts, dtype=torch.bool)
    for path in args.policies:
        ok = success(fly_condition(path, args.row, num_starts=args.num_starts, seed=args.seed))
        print(f"{path}: {ok.float().mean().item():.2f} on {args.row!r} (seed {args.seed})", flush=True)
        missed &= ~ok
    spec, _ = load_policy(args.policies[0])
    nominal = spec.nominal_airframe
    starts, wind, flown = row.world(nominal, args.num_starts, args.seed)
    indices = torch.nonzero(missed).flatten().tolist()
    print(f"# {len(indices)} starts no policy flies; searching {budget.population} x {budget.iterations} plans each")
    saved = []
    for i in indices:
        t = time.perf_counter()
        r = search_start(
            starts[i],
            nominal,
            flown,
            spec.control_hz,
            budget,
            seed=i,
            start_motors=row.start_motors,
            wind=None if wind is None else wind[i],
        )
        s = starts[i]
        what = "saved" if r.saved else f"not found (closest plan crashes at {r.first_crash_s:.2f} s)"
        print(
            f"start {i:3d} (z {s[2]:.2f} m, roll {s[3]:+.2f}, pitch {s[4]:+.2f} rad): {what}, "
            f"{r.rollouts} rollouts, {time.perf_counter() - t:.0f} s",
            flush=True,
        )
        saved.append(r.saved)
    flown_by_one = args.num_starts - len(indices)
    print(
        f"flown by a policy {flown_by_one}, saved by the search {sum(saved)}, "
        f"not found {len(saved) - sum(saved)}: at least {(flown_by_one + sum(saved)) / args.num_starts:.2f} "
        f"of the row's starts can be kept from crashing"
    )


if __name__ == "__main__":
    main()
