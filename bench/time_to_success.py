"""Wall-clock and frames until the protocol's success rate first reaches 0.905 (the paper's BFC)
and 0.99, for the default training config, one training run per seed (run one after another:
never two trainings at once on 2 cores).

    python bench/time_to_success.py --seeds 0 1 2 [-- extra train.py overrides]

Prints a Markdown table; each run's directory (TensorBoard, summary.json) is kept under
outputs/bench/. Two clocks: "training" counts collection and update only (summary.json's
wall_seconds); "from launch" counts from the moment `python train.py` is started until the
in-training evaluation that first reached the level ended (imports, set-up and every evaluation
included: the time a user waits). The machine's raw MuJoCo speed (256 envs, in-air hover, at the
run's control rate, at the training step and at the reference 0.002 s that evaluations fly) is
printed first, so other machines can scale the figures.
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
    return f"{reach['wall_seconds']:.0f} s ({reach['frames'] / 1e6:.2f}M)"


def from_launch(history: list, level: float, launched: float) -> str:
    """Seconds from launching train.py to the end of the first evaluation at >= level."""
    for h in history:
        if h["eval/success_rate"] >= level and "unix_seconds" in h:
            return f"{h['unix_seconds'] - launched:.0f} s"
    return "not reached"


def raw_mujoco_rate(overrides: list[str], physics_dt: float | None = None) -> float:
    """Raw MuJoCo steps/s at 256 envs for the config's control rate (bench/env_throughput.py), at
    the training step (physics_dt None) or the given one."""
    import torch
    from env_throughput import hover_rate  # bench/ is the script's directory

    from bfc.config import compose
    from bfc.factory import make_base_env

    torch.set_num_threads(1)
    cfg = compose([*overrides, *([f"env.physics_dt={physics_dt}"] if physics_dt else [])])
    env = make_base_env(cfg, num_envs=256, randomize=False)
    rate = max(hover_rate(env, 200) for _ in range(3))
    env.close()
    return rate


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--out", default=str(ROOT / "outputs" / "bench" / time.strftime("%Y-%m-%d_%H-%M-%S")))
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. env.control_hz=250")
    args = p.parse_args()
    print(
        f"# {platform.machine()}, {platform.python_version()}; overrides: {' '.join(args.overrides) or '(defaults)'}; "
        f"raw MuJoCo (256 envs, in-air hover, best of 3) {raw_mujoco_rate(args.overrides):,.0f} steps/s at the "
        f"training step, {raw_mujoco_rate(args.overrides, 0.002):,.0f} at the reference 0.002 s"
    )
    print(
        "| seed | 0.905 reached after (training) | from launch | 0.99 reached after (training) | from launch "
        "| final success | last three evaluations | whole run | frames/s overall | collection frames/s "
        "| update s/batch |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        run_dir = Path(args.out) / f"seed{seed}"
        cmd = [sys.executable, "train.py", f"seed={seed}", "logger.progress=false", f"hydra.run.dir={run_dir}"]
        launched = time.time()
        subprocess.run(cmd + args.overrides, cwd=ROOT, check=True, stdout=subprocess.DEVNULL)
        whole = time.time() - launched
        s = json.loads((run_dir / "summary.json").read_text())
        h = s["history"]
        last_three = ", ".join(f"{e['eval/success_rate']:.2f}" for e in h[-3:])
        print(
            f"| {seed} | {fmt(s['first_reached_0.905'])} | {from_launch(h, 0.905, launched)} "
            f"| {fmt(s['first_reached_0.99'])} | {from_launch(h, 0.99, launched)} "
            f"| {s['final_success_rate']:.2f} | {last_three} "
            f"| {whole / 60:.1f} min | {s['frames'] / s['wall_seconds']:,.0f} "
            f"| {s['collection_frames_per_second']:,} | {s['update_seconds_per_batch']} |",
            flush=True,
        )


if __name__ == "__main__":
    main()
