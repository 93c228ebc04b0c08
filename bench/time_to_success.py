"""Wall-clock and frames until the protocol's success rate first reaches 0.905 (the paper's BFC)
and 0.99, for the default training config, one training run per seed (run one after another:
never two trainings at once on 2 cores).

    python bench/time_to_success.py --seeds 0 1 2 [-- extra train.py overrides]

Prints a Markdown table; each run's directory (TensorBoard, summary.json) is kept under
outputs/bench/. Wall-clock counts collection, update and the in-training evaluations.
"""

from __future__ import annotations

import argparse
import json
import platform
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def fmt(reach) -> str:
    if reach is None:
        return "not reached"
    return f"{reach['wall_seconds'] / 60:.1f} min ({reach['frames'] / 1e6:.0f}M)"


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--out", default=str(ROOT / "outputs" / "bench" / time.strftime("%Y-%m-%d_%H-%M-%S")))
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. env.control_hz=250")
    args = p.parse_args()
    print(f"# {platform.machine()}, {platform.python_version()}; overrides: {' '.join(args.overrides) or '(defaults)'}")
    print(
        "| seed | 0.905 reached after | 0.99 reached after | final success | best | frames/s overall "
        "| collection frames/s | update s/batch |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        run_dir = Path(args.out) / f"seed{seed}"
        cmd = [sys.executable, "train.py", f"seed={seed}", "logger.progress=false", f"hydra.run.dir={run_dir}"]
        subprocess.run(cmd + args.overrides, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        s = json.loads((run_dir / "summary.json").read_text())
        print(
            f"| {seed} | {fmt(s['first_reached_0.905'])} | {fmt(s['first_reached_0.99'])} "
            f"| {s['final_success_rate']:.2f} | {s['best_success_rate']:.2f} | {s['frames'] / s['wall_seconds']:,.0f} "
            f"| {s['collection_frames_per_second']:,} | {s['update_seconds_per_batch']} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
