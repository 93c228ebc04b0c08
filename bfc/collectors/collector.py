"""`make_collector`: the collector `collector.kind` names (TorchRL's, resumable, or bfc's fused one
that gives the same batches), and per-batch episode statistics."""

from __future__ import annotations

import torch
from tensordict import TensorDictBase

from bfc import keys


def make_collector(env, net, frames_per_batch: int, total_frames: int, kind: str = "torchrl"):
    """The collector `collector.kind` names over `env`, flying the policy network `net`: batches of
    shape (num_envs, frames_per_batch / num_envs). "torchrl": TorchRL's synchronous Collector
    (`ResumableCollector`, through `SamplingActor`); "fused": `FusedCollector`, the same batches.
    Either way torch's global generator is left as it was found: TorchRL's Collector draws from it
    while it is built, and runs of both kinds must start collecting from the same state."""
    from bfc.agent import SamplingActor
    from bfc.collectors.fused import FusedCollector

    rng = torch.get_rng_state()
    if kind == "fused":
        collector = FusedCollector(env, net, frames_per_batch, total_frames)
    elif kind == "torchrl":
        from bfc.collectors.torchrl_collector import ResumableCollector

        collector = ResumableCollector(
            env,
            SamplingActor(net),
            frames_per_batch=frames_per_batch,
            total_frames=total_frames,
            device="cpu",
            split_trajs=False,
            track_traj_ids=False,
            auto_register_policy_transforms=False,
        )
    else:
        raise ValueError(f"collector.kind must be fused or torchrl, got {kind!r}")
    torch.set_rng_state(rng)
    return collector


def episode_stats(data: TensorDictBase) -> dict[str, float]:
    """Return, length and crash share of the episodes that ended in this batch (empty if none)."""
    done = data.get(("next", keys.DONE)).squeeze(-1)
    if not bool(done.any()):
        return {}
    terminated = data.get(("next", keys.TERMINATED)).squeeze(-1)[done]
    return {
        "train/episode_return": data.get(("next", "episode_reward"))[done].mean().item(),
        "train/episode_length": data.get(("next", "step_count"))[done].float().mean().item(),
        "train/crash_rate": terminated.float().mean().item(),
        "train/episodes": float(done.sum()),
    }
