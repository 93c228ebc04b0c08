"""Time of one PPO update (GAE + epochs x minibatches) on a batch collected by the default
config's env, per network size, activation, torch thread count and loss path.

    python bench/update_time.py [--threads 1 2] [--sizes 64,64 64,128 128x3,128] [--activations tanh relu]

A size is "actor,critic", each a width (two hidden layers) or WIDTHxDEPTH.

"bfc" is what training runs (`loss.implementation=bfc`, bfc.training.ppo_step: the step with its
gradients written out, one flat Adam); "torchrl" is `loss.implementation=torchrl`: TorchRL's
ClipPPOLoss on TensorDict minibatches, autograd and torch's Adam. The rows are measured in
alternating rounds and the medians printed (shared cores change speed), each beside the machine's
raw MuJoCo speed (bench/env_throughput.py's figure, so that machines can be compared).
"""

from __future__ import annotations

import argparse
import statistics
import time

import torch
from time_to_success import raw_mujoco_rate  # bench/ is the script's directory

from bfc.agent import PolicySpec, make_critic, torchrl_actor
from bfc.config import compose, minibatch_size
from bfc.factory import make_env
from bfc.training.ppo import PPO

IMPLEMENTATIONS = ("bfc", "torchrl")  # loss.implementation


def layers(size: str) -> list[int]:
    """Hidden layer widths: 128 -> [128, 128]; 128x3 -> [128, 128, 128]."""
    width, _, depth = size.partition("x")
    return [int(width)] * int(depth or 2)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--sizes", nargs="+", default=["64,64", "64,128"], help="actor,critic (e.g. 128,128 or 128x3,128)")
    p.add_argument("--activations", nargs="+", default=["relu"])
    p.add_argument("--rounds", type=int, default=5)
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. loss.num_minibatches=8")
    args = p.parse_args()
    cfg = compose(list(args.overrides))
    env = make_env(cfg, seed=0)
    steps = cfg.collector.frames_per_batch // cfg.env.num_envs
    c, lo = cfg.collector, cfg.loss
    print(
        f"# batch {c.frames_per_batch} frames, {lo.epochs} epochs, minibatch {minibatch_size(cfg)};"
        f" medians of {args.rounds} rounds"
    )
    print(f"# raw MuJoCo: {raw_mujoco_rate(list(args.overrides)):,.0f} steps/s at 256 envs")
    print("| actor | critic | activation | torch threads | bfc (s) | torchrl (s) | ratio |")
    print("|---|---|---|---|---|---|---|")
    for size in args.sizes:
        for act in args.activations:
            a, w = size.split(",")
            cfg.model.activation, cfg.model.actor_hidden, cfg.model.critic_hidden = act, layers(a), layers(w)
            learners, data = {}, None
            for implementation in IMPLEMENTATIONS:
                cfg.loss.implementation = implementation
                torch.manual_seed(0)
                spec = PolicySpec.from_config(cfg)
                net = spec.make_net()
                actor = torchrl_actor(net, env.action_spec)
                critic = make_critic(spec.observation_size, cfg.model.critic_hidden, act, net.obs_norm)
                if data is None:
                    with torch.no_grad():
                        data = env.rollout(steps, actor, break_when_any_done=False)
                learners[implementation] = PPO(cfg, actor, critic)
            for threads in args.threads:
                torch.set_num_threads(threads)
                times = {name: [] for name in IMPLEMENTATIONS}
                for _ in range(args.rounds):
                    for name, learner in learners.items():
                        t = time.perf_counter()
                        learner.update(data.clone())
                        times[name].append(time.perf_counter() - t)
                f, r = (statistics.median(times[k]) for k in IMPLEMENTATIONS)
                print(f"| {a} | {w} | {act} | {threads} | {f:.3f} | {r:.3f} | {f / r:.2f} |", flush=True)


if __name__ == "__main__":
    main()
