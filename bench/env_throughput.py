"""Env steps per second of QuadrotorEnv against raw MuJoCo stepping of the same model.

    python bench/env_throughput.py [--envs 64 256 1024] [--steps 300] [--threads 2]

The ceiling ("raw") is one threaded `mujoco.rollout` call per control step with fixed hover
thrust: the MuJoCo integration alone, with no motor model, observation, reward or TensorDict.
Both start from the same states, in the air at 1-2 m and level, so both integrate the same
(contact-free) physics; the env gets random motor commands within +/-20% of hover speed and
auto-resets through `step_and_maybe_reset`, as a collector drives it.
"""

from __future__ import annotations

import argparse
import platform
import time

import mujoco
import numpy as np
import torch

from bfc.envs import QuadrotorEnv


def air_starts(env: QuadrotorEnv) -> torch.Tensor:
    start = torch.zeros(env.num_envs, 12)
    start[:, 2] = 1.0 + torch.rand(env.num_envs, generator=torch.Generator().manual_seed(1))
    return start


def raw_rate(env: QuadrotorEnv, steps: int) -> float:
    n, nsub = env.num_envs, env.substeps
    env.reset(env.reset().set("start_state", air_starts(env)))
    state0 = env._physics_np.copy()
    ctrl = np.zeros((n, nsub, env.model.nu))
    ctrl[:, :, :4] = env.airframe.motor_constant * env.hover_speed**2
    out = np.zeros((n, nsub, state0.shape[1]))
    models = [env.model] * n
    with mujoco.rollout.Rollout(nthread=env.num_threads) as pool:

        def once():
            pool.rollout(models, env._datas, state0, ctrl, state=out, skip_checks=True, nstep=nsub)
            state0[:] = out[:, -1]

        for _ in range(20):
            once()
        t = time.perf_counter()
        for _ in range(steps):
            once()
        return n * steps / (time.perf_counter() - t)


def env_rate(env: QuadrotorEnv, steps: int) -> float:
    td = env.reset(env.reset().set("start_state", air_starts(env)))
    gen = torch.Generator().manual_seed(0)
    low, high = 0.8 * env.hover_speed, 1.2 * env.hover_speed
    actions = [low + (high - low) * torch.rand(env.num_envs, 4, generator=gen) for _ in range(16)]
    for i in range(20):
        td = env.step_and_maybe_reset(td.set("action", actions[i % 16]))[1]
    t = time.perf_counter()
    for i in range(steps):
        td = env.step_and_maybe_reset(td.set("action", actions[i % 16]))[1]
    return env.num_envs * steps / (time.perf_counter() - t)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[64, 256, 1024])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--control-hz", type=float, default=250.0)
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(
        f"# {platform.processor() or platform.machine()}, {torch.get_num_threads()} torch thread(s), "
        f"mujoco {mujoco.__version__}, torch {torch.__version__}, control {args.control_hz:g} Hz"
    )
    print("| envs | raw MuJoCo (steps/s) | QuadrotorEnv, random actions (steps/s) | ratio |")
    print("|---|---|---|---|")
    for n in args.envs:
        env = QuadrotorEnv(n, control_hz=args.control_hz, num_threads=args.threads, seed=0)
        raw = raw_rate(env, args.steps)
        ours = env_rate(env, args.steps)
        print(f"| {n} | {raw:,.0f} | {ours:,.0f} | {ours / raw:.2f} |", flush=True)
        env.close()


if __name__ == "__main__":
    main()
