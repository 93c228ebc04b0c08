"""Tune the classical baselines for an airframe on the validation starts: a grid of gain factors,
every candidate flown side by side (one env per start and candidate) on every row of suite=robust
and suite=hardware.

    python bench/tune_baselines.py --airframe crazyflie [--starts 30] [--json out.json]

Lee and lee_i (Lee with an integral): the position, velocity, attitude and angular-rate gains (each
already scaled to the airframe by mass and inertia) times 0.5, 1 or 2 (81 candidates each).
The MPC: its inner loop's attitude and rate gains times 0.5, 1 or 2 (9 candidates; its QP weights
are one Hessian shared by all envs, so they stay the published set). Each candidate's score is its
mean success over the rows, ties broken by the lower mean hover error, then by the fewer factors
away from 1. The rows are those of suite=robust and suite=hardware (latency, estimator noise, the
throw): a gain that wins the first and crashes at 20 ms of latency is no choice. The choice is
printed as the entry of bfc/controllers/tuned.py's TUNED; the test starts (seed 0) are never flown.
"""

from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import platform
import time

import torch

from bfc.config import airframe_params, builtin_airframes
from bfc.controllers import build
from bfc.evaluation import VALIDATION_SEED, fly
from bfc.evaluation.flying import PROTOCOL_HZ
from bfc.evaluation.judge import judge
from bfc.evaluation.metrics import hover_errors
from bfc.evaluation.suites import SUITES, condition

FACTORS = (0.5, 1.0, 2.0)
LEE_GROUPS = ("position", "velocity", "attitude", "angular_rate")
GRIDS = {"lee": LEE_GROUPS, "lee_i": LEE_GROUPS, "mpc": ("attitude", "angular_rate")}


def candidates(groups) -> list[dict]:
    return [dict(zip(groups, combo, strict=True)) for combo in itertools.product(FACTORS, repeat=len(groups))]


def fly_grid(name: str, grid: list[dict], airframe, row: str, n: int, seconds: float):
    """(success (k, n) bool, hover error (k, n) m) of each candidate on the row's n validation starts."""
    k, c = len(grid), condition(row)
    starts, wind, flown = c.world(airframe, n, VALIDATION_SEED)
    controller = build(name, airframe, 1.0 / PROTOCOL_HZ, tuned=False)
    controller.scale_gains(
        **{g: torch.tensor([c[g] for c in grid], dtype=torch.float64).repeat_interleave(n) for g in grid[0]}
    )
    flights = fly(
        controller,
        starts.repeat(k, 1),
        seconds=seconds,
        seed=VALIDATION_SEED,
        control_hz=PROTOCOL_HZ,
        airframe=flown,
        external_force=None if wind is None else wind.repeat(k, 1),
        nominal=dataclasses.asdict(airframe),
        **c.hardware(),
    )
    return judge(flights).success.reshape(k, n), hover_errors(flights).reshape(k, n)


def tune(name: str, airframe, rows, n: int, seconds: float) -> list[dict]:
    """Every candidate with its per-row success and hover error, best first."""
    grid = candidates(GRIDS[name])
    per_row = {}
    for row in rows:
        t0 = time.perf_counter()
        ok, err = fly_grid(name, grid, airframe, row, n, seconds)
        per_row[row] = (ok.float().mean(1), torch.where(ok, err, torch.nan).nanmedian(1).values)
        print(f"  {name} {row}: {len(grid)} candidates x {n} starts in {time.perf_counter() - t0:.0f} s", flush=True)
    scored = []
    for i, c in enumerate(grid):
        success = {row: float(s[i]) for row, (s, _) in per_row.items()}
        hover = [float(e[i]) for _, e in per_row.values() if not torch.isnan(e[i])]
        scored.append(
            {
                "factors": c,
                "success": sum(success.values()) / len(success),
                "hover_error_m": sum(hover) / len(hover) if hover else float("inf"),
                "rows": success,
            }
        )
    return rank(scored)


def rank(scored: list[dict]) -> list[dict]:
    """Best first: mean success (to 1e-6: means of the same counts summed in another order tie),
    then the lower mean hover error, then the fewer factors away from 1."""
    return sorted(
        scored,
        key=lambda s: (-round(s["success"], 6), s["hover_error_m"], sum(f != 1.0 for f in s["factors"].values())),
    )


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--airframe", default="crazyflie", choices=builtin_airframes())
    p.add_argument("--starts", type=int, default=30, help="validation starts per row and candidate")
    p.add_argument("--seconds", type=float, default=10.0)
    p.add_argument("--controllers", nargs="+", default=list(GRIDS), choices=list(GRIDS))
    p.add_argument("--suites", nargs="+", default=list(SUITES), choices=list(SUITES), help="whose rows score")
    p.add_argument("--json", default=None, help="write every candidate's scores here")
    p.add_argument("--from-json", default=None, help="rank and print the scores a --json run wrote, flying nothing")
    args = p.parse_args()
    airframe = airframe_params(args.airframe)
    rows = [row for suite in args.suites for row in SUITES[suite]]
    n, seed = args.starts, VALIDATION_SEED
    print(f"# {platform.machine()}; {args.airframe}; {n} validation starts (seed {seed}) x {len(rows)} rows")
    out, done = {}, {}
    if args.from_json:
        with open(args.from_json) as f:
            done = json.load(f)
    for name in args.controllers:
        ranked = rank(done[name]) if name in done else tune(name, airframe, rows, args.starts, args.seconds)
        out[name] = ranked
        untuned = next(s for s in ranked if all(f == 1.0 for f in s["factors"].values()))
        print(f"\n## {name}: best of {len(ranked)} (mean success over {len(rows)} rows, mean hover error)")
        print("| factors | success | hover error | " + " | ".join(rows) + " |")
        print("|---|---|---|" + "---|" * len(rows))
        for s in [*ranked[:5], untuned] if untuned not in ranked[:5] else ranked[:5]:
            tag = " (untuned)" if s is untuned else ""
            cells = " | ".join(f"{s['rows'][r]:.2f}" for r in rows)
            factors = ", ".join(f"{g} {f:g}" for g, f in s["factors"].items())
            print(f"| {factors}{tag} | {s['success']:.3f} | {100 * s['hover_error_m']:.2f} cm | {cells} |")
        best = {g: f for g, f in ranked[0]["factors"].items() if f != 1.0}
        print(f'\nTUNED["{args.airframe}"]["{name}"] = {best}')
    if args.json:
        with open(args.json, "w") as f:
            json.dump(out, f, indent=1)


if __name__ == "__main__":
    main()
