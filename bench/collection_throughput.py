"""Collection frames per second: bfc's fused collector and TorchRL's Collector over the same env,
against raw MuJoCo at the same control rate and env count.

    python bench/collection_throughput.py [--envs 256 1024 2048] [--batches 4] [--rounds 3]
                                          [--policy pretrained/policy.pt] [-- train.py overrides]

Each row collects `--batches` batches of `--steps` steps per env with the config's env (the full
training stack: TDTS, JD, CSS, the policy's maps, episode statistics) and the policy's weights
(`--policy`; a trained policy flies long episodes, as mid-training collection does), one torch
thread, MuJoCo's threads as the config says: "fused" is `collector.kind=fused` (the default),
"torchrl" TorchRL's `Collector` (the same batches bit for bit: tests/test_pipeline.py).
"raw MuJoCo" is one threaded `mujoco.rollout` call per control step of the same model and env
count, held at hover in the air (no motor model, observation, reward, reset or policy). Shared
cloud cores change speed from one second to the next, so the rows are measured in alternating
rounds and the medians printed.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import time

import torch
from env_throughput import hover_rate  # bench/ is the script's directory

from bfc.agent import PolicySpec, read_policy
from bfc.collectors import make_collector
from bfc.config import compose
from bfc.factory import make_base_env, make_env


def rate(kind: str, cfg, net, batches: int) -> float:
    env = make_env(cfg, seed=0)
    fpb = int(cfg.collector.frames_per_batch)
    collector = make_collector(env, net, fpb, fpb * (batches + 1), kind=kind)
    it = iter(collector)
    next(it)  # warm-up: the first batch starts every episode at once
    t = time.perf_counter()
    frames = sum(next(it).numel() for _ in range(batches))
    seconds = time.perf_counter() - t
    collector.shutdown()
    env.close()
    return frames / seconds


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--envs", type=int, nargs="+", default=[256, 1024, 2048])
    p.add_argument("--steps", type=int, default=32, help="steps per env in a batch")
    p.add_argument("--batches", type=int, default=4)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--policy", default="pretrained/policy.pt")
    p.add_argument("--kinds", nargs="+", default=["fused", "torchrl"])
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. env.control_hz=250")
    args = p.parse_args()
    torch.set_num_threads(1)
    print(f"# {platform.machine()}, torch {torch.__version__}; policy {args.policy}; medians of {args.rounds} rounds")
    print("| envs | " + " | ".join(f"{k} (frames/s)" for k in args.kinds) + " | raw MuJoCo (steps/s) | fused / raw |")
    print("|---|" + "---|" * (len(args.kinds) + 2))
    for n in args.envs:
        cfg = compose([f"env.num_envs={n}", f"collector.frames_per_batch={n * args.steps}", *args.overrides])
        net = PolicySpec.from_config(cfg).make_net()
        if args.policy:
            net.load_state_dict(read_policy(args.policy).state_dict)
        base = make_base_env(cfg, randomize=False)
        rates = {k: [] for k in (*args.kinds, "raw")}
        for _ in range(args.rounds):
            rates["raw"].append(hover_rate(base, 200))
            for kind in args.kinds:
                rates[kind].append(rate(kind, cfg, net, args.batches))
        base.close()
        med = {k: statistics.median(v) for k, v in rates.items()}
        cells = " | ".join(f"{med[k]:,.0f}" for k in args.kinds)
        ratio = f"{med['fused'] / med['raw']:.2f}" if "fused" in med else "n/a"
        print(f"| {n} | {cells} | {med['raw']:,.0f} | {ratio} |", flush=True)


if __name__ == "__main__":
    main()
