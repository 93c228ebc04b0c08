"""Time of one PPO update (GAE + epochs x minibatches) on a synthetic batch, per network size and
torch thread count.

    python bench/update_time.py [--threads 1 2] [--sizes 64,128 256,256] [--activations tanh relu]
"""

from __future__ import annotations

import argparse
import time

import torch
from omegaconf import OmegaConf

from bfc.config import Config, minibatch_size
from bfc.factory import find_transform, make_env
from bfc.training.ppo import make_loss, make_models, ppo_update
from bfc.transforms import PolicyObservation


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--threads", type=int, nargs="+", default=[1, 2])
    p.add_argument("--sizes", nargs="+", default=["64,128", "128,128", "256,256"], help="actor width,critic width")
    p.add_argument("--repeats", type=int, default=3)
    p.add_argument("--activations", nargs="+", default=["tanh", "relu"])
    args = p.parse_args()
    cfg = OmegaConf.structured(Config)
    env = make_env(cfg, seed=0)
    obs = find_transform(env, PolicyObservation)
    steps = cfg.collector.frames_per_batch // cfg.env.num_envs
    c, lo = cfg.collector, cfg.loss
    print(f"# batch {c.frames_per_batch} frames, {lo.epochs} epochs, minibatch {minibatch_size(cfg)}")
    print("| actor x2 | critic x2 | activation | torch threads | update (s) |")
    print("|---|---|---|---|---|")
    for size, act in [(s, a) for s in args.sizes for a in args.activations]:
        cfg.model.activation = act
        a, c = (int(v) for v in size.split(","))
        cfg.model.actor_hidden, cfg.model.critic_hidden = [a, a], [c, c]
        actor, critic = make_models(cfg, obs.size, env.action_spec)
        with torch.no_grad():
            data = env.rollout(steps, actor, break_when_any_done=False)
        loss, adv = make_loss(cfg, actor, critic)
        opt = torch.optim.Adam(loss.parameters(), lr=cfg.optim.lr)
        for threads in args.threads:
            torch.set_num_threads(threads)
            ppo_update(data.clone(), loss, adv, opt, cfg)
            t = time.perf_counter()
            for _ in range(args.repeats):
                ppo_update(data.clone(), loss, adv, opt, cfg)
            dt = (time.perf_counter() - t) / args.repeats
            print(f"| {a} | {c} | {act} | {threads} | {dt:.2f} |", flush=True)


if __name__ == "__main__":
    main()
