"""Collection frames per second of the training pipeline against raw MuJoCo at the same control
rate and env count, and what each hot-path lever is worth.

    python bench/collection_throughput.py [--batches 4] [--rounds 3] [--policy p.pt] [-- train.py overrides]
    python bench/collection_throughput.py --breakdown [--policy p.pt]   # where a collection step's time goes

Each row collects `--batches` batches with TorchRL's Collector over the config's env (the full
transform stack: TDTS, JD, CSS, observation, action map, episode statistics) and an untrained
policy (or `--policy`'s weights), as `train.py` does, every path from the same collector
state, with one torch thread (MuJoCo's rollout threads own the cores):
- "bfc": what training runs (the fused partial reset `BFCEnv.maybe_reset`, the plain-torch
  sampling actor `bfc.agent.SamplingActor`);
- "TorchRL reset": TorchRL's generic `maybe_reset` instead of the fused one;
- "TorchRL reset and actor": also the ProbabilisticActor itself (the code before both levers).
All three produce the same batches bit for bit (tests/training/test_hot_path.py).
The ceiling, "raw MuJoCo", is one threaded `mujoco.rollout` call per control step of the same
model, env count and substeps, held at hover thrust in the air (no motor model, observation,
reward, reset or TensorDict). Shared cloud cores change speed from one second to the next, so the
rows are measured in alternating rounds and the medians compared.
"""

from __future__ import annotations

import argparse
import platform
import statistics
import tempfile
import time

import mujoco
import torch
from env_throughput import hover_rate  # bench/ is the script's directory

from bfc.agent import read_policy
from bfc.config import compose
from bfc.training.runner import Runner

VARIANTS = {
    "bfc": dict(fused_reset=True, sampling_actor=True),
    "TorchRL reset": dict(fused_reset=False, sampling_actor=True),
    "TorchRL reset and actor": dict(fused_reset=False, sampling_actor=False),
}


def collection_rate(runner: Runner, start: dict, batches: int, fused_reset: bool, sampling_actor: bool) -> float:
    """Frames/s of `batches` batches collected from the collector state `start` (every path
    collects the same frames)."""
    runner.env.fused_reset = fused_reset
    collector = runner.collector
    collector.load_state_dict(start)
    policy = collector.policy
    if not sampling_actor:
        collector.policy = collector._wrapped_policy = runner.actor
    try:
        it = iter(collector)
        t = time.perf_counter()
        frames = sum(next(it).numel() for _ in range(batches))
        return frames / (time.perf_counter() - t)
    finally:
        collector.policy = collector._wrapped_policy = policy
        runner.env.fused_reset = True


def breakdown(runner: Runner, start: dict, batches: int) -> None:
    """Time per collection step of each piece (MuJoCo, the env's own step and reset, every
    transform's step, reset and pre-reset, the policy), by wrapping each in a timer; what is
    left is TorchRL's and the Collector's bookkeeping."""
    times: dict[str, float] = {}

    def timed(obj, name: str, label: str) -> None:
        inner = getattr(obj, name)

        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            try:
                return inner(*args, **kwargs)
            finally:
                times[label] = times.get(label, 0.0) + time.perf_counter() - t

        setattr(obj, name, wrapper)

    base, collector = runner.env.base_env, runner.collector
    timed(base, "_integrate", "MuJoCo (mujoco.rollout)")
    timed(base, "_step", "env step (MuJoCo included)")
    timed(base, "_reset", "env reset")
    for t in runner.env.transform:
        name = type(t).__name__
        timed(t, "_step", f"{name} step")
        timed(t, "_reset", f"{name} reset")
        timed(t, "_reset_env_preprocess", f"{name} pre-reset")
    timed(collector.policy, "forward", "policy")
    collector.load_state_dict(start)
    it = iter(collector)
    t0 = time.perf_counter()
    steps = sum(next(it).shape[-1] for _ in range(batches))
    total = time.perf_counter() - t0
    own = sum(v for k, v in times.items() if k != "MuJoCo (mujoco.rollout)")
    print(f"| piece | ms per {base.num_envs}-env step |")
    print("|---|---|")
    for label, seconds in sorted(times.items(), key=lambda kv: -kv[1]):
        if seconds / steps * 1e3 >= 0.01:
            print(f"| {label} | {seconds / steps * 1e3:.2f} |")
    print(f"| TorchRL and Collector bookkeeping (the rest) | {(total - own) / steps * 1e3:.2f} |")
    print(f"| **total** | **{total / steps * 1e3:.2f}** |")


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--batches", type=int, default=4)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--policy", default=None, help="fly this policy.pt's weights (the config's observation)")
    p.add_argument("--breakdown", action="store_true", help="time each piece of a collection step instead")
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. env.control_hz=250")
    args = p.parse_args()
    torch.set_num_threads(1)
    cfg = compose(["logger.tensorboard=false", "logger.progress=false", *args.overrides])
    runner = Runner(cfg, tempfile.mkdtemp())
    if args.policy:  # a trained policy flies long episodes, as mid-training collection does
        runner.net.load_state_dict(read_policy(args.policy).state_dict)
    base = runner.env.base_env
    next(iter(runner.collector))  # warm-up
    start = runner.collector.state_dict()
    if args.breakdown:
        breakdown(runner, start, args.batches)
        return runner.close()
    rates: dict[str, list[float]] = {"raw MuJoCo": [], **{name: [] for name in VARIANTS}}
    for _ in range(args.rounds):
        rates["raw MuJoCo"].append(hover_rate(base, 300))
        for name, levers in VARIANTS.items():
            rates[name].append(collection_rate(runner, start, args.batches, **levers))
    runner.close()
    raw = statistics.median(rates["raw MuJoCo"])
    print(
        f"# {platform.processor() or platform.machine()}, mujoco {mujoco.__version__}, torch {torch.__version__}; "
        f"{base.num_envs} envs at {base.control_hz:g} Hz ({base.substeps} physics substeps), variant {cfg.variant}; "
        f"policy {args.policy or 'untrained'}; medians of {args.rounds} alternating rounds of {args.batches} "
        f"batches of {cfg.collector.frames_per_batch}"
    )
    print("| path | frames/s | ratio to raw MuJoCo | time per 256-env step (ms) |")
    print("|---|---|---|---|")
    for name, values in rates.items():
        rate = statistics.median(values)
        print(f"| {name} | {rate:,.0f} | {rate / raw:.2f} | {base.num_envs / rate * 1e3:.2f} |")


if __name__ == "__main__":
    main()
