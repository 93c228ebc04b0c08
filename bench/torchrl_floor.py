"""The per-step cost of TorchRL itself, with no physics: how close to raw MuJoCo any TorchRL env
and Collector can get on this machine.

    python bench/torchrl_floor.py [--envs 256] [--steps 2000] [--rounds 5] [--control-hz 100] [--physics-dt 0.01]

`NullEnv` is an `EnvBase` with QuadrotorEnv's specs (batch, observation, action, reward, done)
whose `_step` and `_reset` do nothing but hand back preallocated tensors: what is left is
TorchRL's own work per step (spec bookkeeping, TensorDict building, `step_mdp`, done handling).
The Collector row drives it with a one-layer policy and no transforms. Raw MuJoCo is one
threaded `mujoco.rollout` call per control step of the project's model (in-air hover,
bench/env_throughput.py's ceiling). The best ratio to raw that any env (or collection) built on
these layers can reach is raw / (raw + floor): the Python that TorchRL runs per step alone.
"""

from __future__ import annotations

import argparse
import platform
import time

import mujoco
import numpy as np
import torch
from env_throughput import hover_rate  # bench/ is the script's directory
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.collectors import Collector
from torchrl.envs import EnvBase

from bfc.envs import QuadrotorEnv


class NullEnv(EnvBase):
    """QuadrotorEnv's specs, no physics: every step returns the same preallocated tensors."""

    def __init__(self, like: QuadrotorEnv):
        super().__init__(batch_size=like.batch_size)
        self.observation_spec = like.observation_spec.clone()
        self.action_spec = like.action_spec.clone()
        self.reward_spec = like.reward_spec.clone()
        self.done_spec = like.done_spec.clone()
        self._obs = self.observation_spec.zero()
        self._reward = self.reward_spec.zero()
        self._done = self.done_spec.zero()

    def _out(self, reward: bool) -> TensorDict:
        out = self._obs.clone(recurse=False)
        out.update(self._done.clone(recurse=False))
        if reward:
            out.set("reward", self._reward)
        return out

    def _step(self, tensordict):
        return self._out(reward=True)

    def _reset(self, tensordict=None, **kwargs):
        return self._out(reward=False)

    def _set_seed(self, seed):
        return seed


def env_step_seconds(env: EnvBase, steps: int) -> float:
    td = env.reset()
    action = env.action_spec.zero()
    for _ in range(20):
        td = env.step_and_maybe_reset(td.set("action", action))[1]
    t = time.perf_counter()
    for _ in range(steps):
        td = env.step_and_maybe_reset(td.set("action", action))[1]
    return (time.perf_counter() - t) / steps


def collector_step_seconds(env: EnvBase, steps: int) -> float:
    n = env.batch_size[0]
    obs_dim = env.observation_spec["odometry"].shape[-1]
    act_dim = env.action_spec.shape[-1]
    policy = TensorDictModule(torch.nn.Linear(obs_dim, act_dim), in_keys=["odometry"], out_keys=["action"])
    frames_per_batch = n * 32
    collector = Collector(env, policy, frames_per_batch=frames_per_batch, total_frames=-1)
    batches = max(2, steps // 32)
    it = iter(collector)
    next(it)  # warm-up
    t = time.perf_counter()
    for _ in range(batches):
        next(it)
    seconds = time.perf_counter() - t
    collector.shutdown()
    return seconds / (batches * 32)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--envs", type=int, default=256)
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--rounds", type=int, default=5)
    parser.add_argument("--control-hz", type=float, default=100.0)
    parser.add_argument("--physics-dt", type=float, default=0.01)
    args = parser.parse_args()
    torch.set_num_threads(1)
    real = QuadrotorEnv(args.envs, control_hz=args.control_hz, physics_dt=args.physics_dt, seed=0)
    null = NullEnv(real)
    rounds = []
    for _ in range(args.rounds):  # alternating, medians: shared cloud cores drift
        raw = args.envs / hover_rate(real, 300)
        rounds.append((raw, env_step_seconds(null, args.steps), collector_step_seconds(null, args.steps)))
    raw, env_floor, coll_floor = (float(np.median(r)) for r in zip(*rounds, strict=True))
    real.close()
    print(
        f"# {platform.processor() or platform.machine()}, mujoco {mujoco.__version__}, torch {torch.__version__}, "
        f"{args.envs} envs, control {args.control_hz:g} Hz, physics step {args.physics_dt:g} s; "
        f"medians of {args.rounds} alternating rounds"
    )
    print("| per control step of the whole batch | ms | best ratio to raw MuJoCo reachable on top of it |")
    print("|---|---|---|")
    print(f"| raw MuJoCo (`mujoco.rollout`, in-air hover) | {raw * 1e3:.3f} | 1.00 |")
    print(
        f"| TorchRL `EnvBase.step_and_maybe_reset`, no physics | {env_floor * 1e3:.3f} "
        f"| {raw / (raw + env_floor):.2f} |"
    )
    print(
        f"| TorchRL `Collector`, no physics, a one-layer policy, no transforms | {coll_floor * 1e3:.3f} "
        f"| {raw / (raw + coll_floor):.2f} |"
    )


if __name__ == "__main__":
    main()
