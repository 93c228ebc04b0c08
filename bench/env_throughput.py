"""Env steps per second of QuadrotorEnv against raw MuJoCo stepping of the same model.

    python bench/env_throughput.py [--envs 64 256 1024] [--steps 300] [--threads 2] [--rounds 5]
                                   [--control-hz 100] [--physics-dt 0.01]

`--physics-dt` is MuJoCo's step (default: the reference 0.002 s that evaluations fly; training
takes one step per control step, 0.01 s at 100 Hz).

The env gets random motor commands within +/-20% of hover speed, starting level in the air at
1-2 m, and auto-resets through `step_and_maybe_reset`, as a collector drives it: drones that
crash restart on the floor (the task's start distribution), so part of the batch is in contact.

Two ceilings, both one threaded `mujoco.rollout` call per control step of the same model and
thread count, with no motor model, observation, reward, reset or TensorDict around it:
- "in-air hover": the same starts held at hover thrust (contact-free, the cheapest physics);
- "replay": the env's own integration calls (the states and controls it handed to MuJoCo),
  replayed: exactly the physics the env did, so the gap to it is the env's own overhead.

Shared cloud cores change speed from one second to the next, so the three are measured in
alternating rounds and the medians are compared; "overhead" is the env's extra time per control
step over the replay, for the whole batch.
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


def rollout_rate(env: QuadrotorEnv, calls, carry_state: bool) -> float:
    """Steps/s of `mujoco.rollout` over `calls`, a list of (state (N, 14), ctrl (N, substeps, nu))."""
    n, nsub = env.num_envs, env.substeps
    out = np.zeros((n, nsub, env._nstate))
    models = [env.model] * n
    with mujoco.rollout.Rollout(nthread=env.num_threads) as pool:

        def once(state, ctrl):
            pool.rollout(models, env._datas, state, ctrl, state=out, skip_checks=True, nstep=nsub)
            if carry_state:
                state[:] = out[:, -1]

        for state, ctrl in calls[:20]:
            once(state.copy(), ctrl)
        t = time.perf_counter()
        for state, ctrl in calls:
            once(state, ctrl)
        return n * len(calls) / (time.perf_counter() - t)


def hover_rate(env: QuadrotorEnv, steps: int) -> float:
    env.reset(env.reset().set("start_state", air_starts(env)))
    ctrl = np.zeros((env.num_envs, env.substeps, env.model.nu))
    ctrl[:, :, 2] = 4 * env.airframe.motor_constant * env.hover_speed**2  # the body force: weight
    state = env._physics_np.copy()
    return rollout_rate(env, [(state, ctrl)] * steps, carry_state=True)


def env_rate(env: QuadrotorEnv, steps: int, record: list | None = None) -> float:
    """Steps/s of the env; with `record`, instead collect its integration calls (untimed)."""
    env.set_seed(0)
    td = env.reset(env.reset().set("start_state", air_starts(env)))
    gen = torch.Generator().manual_seed(0)
    low, high = 0.8 * env.hover_speed, 1.2 * env.hover_speed
    actions = [low + (high - low) * torch.rand(env.num_envs, 4, generator=gen) for _ in range(16)]
    for i in range(20):
        td = env.step_and_maybe_reset(td.set("action", actions[i % 16]))[1]
    integrate = env._integrate
    if record is not None:

        def recording():
            record.append((env._physics_np.copy(), env._ctrl_np.copy()))
            integrate()

        env._integrate = recording
    t = time.perf_counter()
    for i in range(steps):
        td = env.step_and_maybe_reset(td.set("action", actions[(20 + i) % 16]))[1]
    rate = env.num_envs * steps / (time.perf_counter() - t)
    env._integrate = integrate
    return rate


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, nargs="+", default=[64, 256, 1024])
    parser.add_argument("--steps", type=int, default=300)
    parser.add_argument("--threads", type=int, default=None)
    parser.add_argument("--control-hz", type=float, default=250.0)
    parser.add_argument("--physics-dt", type=float, default=0.002)
    parser.add_argument("--rounds", type=int, default=5, help="alternating measurements per size")
    args = parser.parse_args()
    torch.set_num_threads(1)
    print(
        f"# {platform.processor() or platform.machine()}, {torch.get_num_threads()} torch thread(s), "
        f"mujoco {mujoco.__version__}, torch {torch.__version__}, control {args.control_hz:g} Hz, "
        f"physics step {args.physics_dt:g} s; "
        f"medians of {args.rounds} alternating rounds of {args.steps} control steps"
    )
    print(
        "| envs | MuJoCo, in-air hover (steps/s) | MuJoCo, the env's calls replayed (steps/s) "
        "| QuadrotorEnv, random actions (steps/s) | ratio to in-air | ratio to replay | overhead per step (us) |"
    )
    print("|---|---|---|---|---|---|---|")
    for n in args.envs:
        env = QuadrotorEnv(n, control_hz=args.control_hz, physics_dt=args.physics_dt, num_threads=args.threads, seed=0)
        calls: list = []
        env_rate(env, args.steps, record=calls)  # the same trajectory as every timed run (same seeds)
        rounds = [
            (hover_rate(env, args.steps), rollout_rate(env, calls, carry_state=False), env_rate(env, args.steps))
            for _ in range(args.rounds)
        ]
        hover, replay, ours = (float(np.median(r)) for r in zip(*rounds, strict=True))
        overhead = (n / ours - n / replay) * 1e6
        print(
            f"| {n} | {hover:,.0f} | {replay:,.0f} | {ours:,.0f} | {ours / hover:.2f} | {ours / replay:.2f} "
            f"| {overhead:,.0f} |",
            flush=True,
        )
        env.close()


if __name__ == "__main__":
    main()
