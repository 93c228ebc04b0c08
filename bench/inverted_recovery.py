"""Recovery from near upside down, on development starts (neither the validation nor the test
starts): the any-attitude suite's weakest case, for comparing training changes without looking
at the starts the docs report.

    python bench/inverted_recovery.py outputs/bench/final/seed1/policy_last.pt ... [--seed 11]

Draws `--num-drawn` any-attitude starts (z 1.5-3 m, at rest, uniform attitude) with `--seed`,
keeps those tilted more than `--min-tilt` degrees, flies each policy from them for 10 s on the
reference simulator and prints the success rate (the protocol's judge). Deterministic; with
`--sampled S` the policies fly actions drawn from their Gaussians (the trained std, torch seed S)
instead of their means: a check of whether failures sit on a tie that noise would break. With
`--by-tilt 150 160 170 175` it also prints the rate in each band of tilt (150-160, ..., 175-180).
"""

from __future__ import annotations

import argparse
from contextlib import contextmanager

import torch

from bfc.agent import GaussianActor
from bfc.evaluation import fly, success
from bfc.evaluation.report import start_tilt_degrees
from bfc.evaluation.suites import any_starts


@contextmanager
def sampled_actions(seed: int | None):
    """Within it, every GaussianActor's mean is a draw from its Gaussian (what training flies)."""
    if seed is None:
        yield
        return
    mean = GaussianActor.forward

    def draw(self, obs):
        loc, scale = mean(self, obs)
        return loc + scale * torch.randn_like(loc), scale

    torch.manual_seed(seed)
    GaussianActor.forward = draw
    try:
        yield
    finally:
        GaussianActor.forward = mean


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", nargs="+", help="policy files")
    p.add_argument("--seed", type=int, default=11, help="development starts (0: test, 1: validation; default 11)")
    p.add_argument("--num-drawn", type=int, default=1000)
    p.add_argument("--min-tilt", type=float, default=120.0, help="degrees between the body and world z axes")
    p.add_argument("--sampled", type=int, default=None, metavar="S", help="fly sampled actions (torch seed S)")
    p.add_argument(
        "--by-tilt", type=float, nargs="+", default=None, metavar="DEG", help="also the rate per tilt band (edges)"
    )
    args = p.parse_args()
    if args.seed in (0, 1):
        p.error("seeds 0 and 1 are the test and validation starts: pick a development seed")
    edges = args.by_tilt or []
    if any(not 0 <= e < 180 for e in edges) or edges != sorted(set(edges)):
        p.error(f"--by-tilt takes rising band edges in [0, 180) degrees, got {edges}")
    starts = any_starts(args.num_drawn, args.seed)
    starts = starts[start_tilt_degrees(starts) > args.min_tilt]
    print(f"# {len(starts)} of {args.num_drawn} any-attitude starts (seed {args.seed}) tilted > {args.min_tilt:g} deg")
    tilt = start_tilt_degrees(starts)
    bands = list(zip(args.by_tilt, [*args.by_tilt[1:], 180.0], strict=True)) if args.by_tilt else []
    if bands:
        print(
            "# starts per band: "
            + ", ".join(f"{lo:g}-{hi:g} deg {int(((tilt > lo) & (tilt <= hi)).sum())}" for lo, hi in bands)
        )
    for path in args.policies:
        with sampled_actions(args.sampled):
            ok = success(fly(path, starts, seconds=10.0, seed=args.seed)).float()
        per_band = [f"{lo:g}-{hi:g} deg {ok[(tilt > lo) & (tilt <= hi)].mean().item():.3f}" for lo, hi in bands]
        print(f"{path}: {ok.mean().item():.3f} recovered" + (f" ({', '.join(per_band)})" if per_band else ""))


if __name__ == "__main__":
    main()
