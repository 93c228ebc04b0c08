"""A row's success rate with its 95% interval, on as many starts as asked: how far a 100-start
figure may sit from the rate the policy flies, and how hard the drawn starts are.

    python bench/row_rates.py pretrained/x500.pt pretrained/crazyflie.pt --rows any harsh --starts 1000
    python bench/row_rates.py mpc --airframe x500 --rows any --starts 100 1000

Each argument is a policy file or a controller name (flown on `--airframe`, default the
Hummingbird). For every row of `evaluate.py suite=robust` or `suite=hardware` named in `--rows`
and every count in `--starts` it prints the successes, the rate and its Wilson 95% interval
(scipy); the crashes, and how many of them left the allowed box (|x| or |y| over 5 m: a throw
braked too late) rather than reaching the floor; and, for the rows whose starts take any
attitude, how many are released more than 150 and 170 deg from upright (a uniform attitude gives
6.7% and 0.76%) with the chance of as many or more in a uniform draw. `--seed 0` (the default) is
the test starts: the first 100 of 1000 are not the 100 (each set is drawn whole from its seed),
so the two counts are two draws. Deterministic: the same figures on every run on one machine.
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import torch
from scipy.stats import binom, binomtest

from bfc.config import CONTROLLER_NAMES, airframe_params
from bfc.envs.params import TerminationParams
from bfc.evaluation.judge import judge
from bfc.evaluation.protocol import TEST_SEED
from bfc.evaluation.report import start_tilt_degrees
from bfc.evaluation.suites import SUITES, condition, fly_condition

TILTS_DEG = (150.0, 170.0)  # what the shares count: the starts the misses come from (docs/evaluation.md)


def uniform_share(deg: float) -> float:
    """Of a uniform attitude, the share tilted more than `deg` from upright (150: 6.7%, 170: 0.76%)."""
    return (1 + math.cos(math.radians(deg))) / 2


def crashes_at_wall(flights) -> tuple[int, int]:
    """(crashes, of them outside the allowed box): where each crashed flight was when it ended."""
    alive = flights.get("alive")
    crashed = ~alive[:, -1]
    end = (~alive).float().argmax(dim=1)  # the first step not alive
    position = flights.get(("state", "position"))[torch.arange(len(end)), end]
    box = TerminationParams()
    outside = (position[:, :2].abs() > box.box_xy).any(-1) | (position[:, 2] > box.box_z)
    return int(crashed.sum()), int((crashed & outside).sum())


def rate_line(label: str, row: str, n: int, seed: int, airframe) -> str:
    flights = fly_condition(label, row, n, seed=seed, airframe=airframe)
    k = int(judge(flights).success.sum())  # the protocol's rule
    ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="wilson")
    crashes, wall = crashes_at_wall(flights)
    interval = f"{ci.low:.3f}-{ci.high:.3f}"
    line = f"| {label} | {row} | {n} (seed {seed}) | {k} | {k / n:.3f} | {interval} | {crashes} ({wall}) |"
    if condition(row).starts not in ("any", "throw"):
        return line + " - |" * len(TILTS_DEG)
    tilt = start_tilt_degrees(condition(row).starts_for(n, seed))
    for deg in TILTS_DEG:
        m = int((tilt > deg).sum())  # and how rare as many or more are in a uniform draw of n
        line += f" {m} (P {binom.sf(m - 1, n, uniform_share(deg)):.3g}) |"
    return line


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("controllers", nargs="+", help="policy files (.pt) or controller names")
    rows = [r for suite in SUITES.values() for r in suite]
    p.add_argument("--rows", nargs="+", default=["any"], help="rows of suite=robust / suite=hardware")
    p.add_argument("--starts", nargs="+", type=int, default=[100, 1000], help="start counts, each a set of its own")
    p.add_argument("--seed", type=int, default=TEST_SEED, help="the starts' seed (0: test, 1: validation)")
    p.add_argument("--airframe", default=None, help="what a controller name flies (a policy flies its own)")
    args = p.parse_args()
    for row in args.rows:
        if row not in rows:
            p.error(f"unknown row {row!r}; rows: {', '.join(rows)}")
    for c in args.controllers:
        if not c.endswith(".pt") and c not in CONTROLLER_NAMES:
            p.error(f"{c!r} is neither a policy file (.pt) nor a controller ({', '.join(sorted(CONTROLLER_NAMES))})")
        if c.endswith(".pt") and not Path(c).is_file():
            p.error(f"no policy file {c}")
    if any(n < 1 for n in args.starts):
        p.error("--starts takes counts >= 1")
    try:
        airframe = airframe_params(args.airframe) if args.airframe else None
    except (ValueError, FileNotFoundError) as err:
        p.error(str(err))
    tilts = " | ".join(f"released > {d:g} deg" for d in TILTS_DEG)
    print(f"| controller | row | starts | successes | rate | 95% interval | crashes (out of the box) | {tilts} |")
    print("|---|---|---|---|---|---|---|" + "---|" * len(TILTS_DEG))
    for c in args.controllers:
        for row in args.rows:
            for n in args.starts:
                print(rate_line(c, row, n, args.seed, airframe), flush=True)
    shares = ", ".join(f"> {d:g} deg {100 * uniform_share(d):.2g}%" for d in TILTS_DEG)
    print(f"(a uniform attitude is released {shares} of the time; P: of as many or more in a uniform draw)")


if __name__ == "__main__":
    main()
