"""Where the hover error under `suite=hardware`'s noisy estimate comes from: each policy flown on
the protocol's starts under the whole of `ESTIMATOR_NOISE`, then under each part of it alone (the
gyro bias, and the white noise on each group of odometry elements), then under all of it with the
white noise scaled (x0.71: the noise power per unit of bandwidth a loop at twice the rate gets
from the row, whose noise is drawn per control step; x0.5).

    python bench/estimator_noise_parts.py pretrained/policy.pt ... [--seed 1 (validation starts)]

Prints a Markdown table of success rate and hover error per part. Deterministic (the noise is
seeded with the starts); about 5 s per part per policy on 2 cores.
"""

from __future__ import annotations

import argparse
import math

from bfc.evaluation.flying import fly
from bfc.evaluation.protocol import TEST_SEED
from bfc.evaluation.suites import ESTIMATOR_NOISE, START_SETS, score

GROUPS = {  # odometry columns (docs/export.md's layout)
    "position": range(0, 3),
    "velocity": range(3, 6),
    "acceleration": range(6, 9),
    "attitude": range(9, 12),
    "body rates": range(12, 15),
    "angular acceleration": range(15, 18),
}


WHITE_SCALES = (1 / math.sqrt(2), 0.5)


def parts() -> dict:
    """{label: a `noise` section}: no noise, all of it, the bias alone, each group's white noise
    alone, all of it with the white noise scaled by each of WHITE_SCALES."""
    zero = [0.0] * 18

    def noise(std, bias):
        return {"kind": "gaussian", "std": std, "bias": bias, "elements": "all"}

    out = {"none": None, "all of it": ESTIMATOR_NOISE, "gyro bias only": noise(zero, ESTIMATOR_NOISE["bias"])}
    for name, columns in GROUPS.items():
        std = [s if i in columns else 0.0 for i, s in enumerate(ESTIMATOR_NOISE["std"])]
        out[f"{name} white noise only"] = noise(std, zero)
    for k in WHITE_SCALES:
        scaled = [k * s for s in ESTIMATOR_NOISE["std"]]
        out[f"all of it, white noise x{k:.2f}"] = noise(scaled, ESTIMATOR_NOISE["bias"])
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", nargs="+", help="policy files (.pt or .onnx)")
    p.add_argument("--seed", type=int, default=TEST_SEED, help="the starts' seed (0: the test starts)")
    p.add_argument("--num-starts", type=int, default=100)
    args = p.parse_args()
    starts = START_SETS["protocol"](args.num_starts, args.seed)
    print(f"# protocol starts (seed {args.seed}), {args.num_starts} flights of 10 s per cell")
    print("| noise | " + " | ".join(args.policies) + " |")
    print("|---|" + "---|" * len(args.policies))
    for label, noise in parts().items():
        cells = []
        for path in args.policies:
            kw = {} if noise is None else {"noise": noise}
            s = score(fly(path, starts, seconds=10.0, seed=args.seed, **kw))
            e = s["hover_error_m"]
            cells.append(f"{s['success_rate']:.2f}, " + ("n/a" if e is None else f"{100 * e:.2f} cm"))
        print(f"| {label} | " + " | ".join(cells) + " |", flush=True)


if __name__ == "__main__":
    main()
