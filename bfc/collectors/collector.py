"""The TorchRL Collector over the batched env, and per-batch episode statistics."""

from __future__ import annotations

from tensordict import TensorDictBase
from torchrl.collectors import Collector

from bfc import keys


def make_collector(env, policy, frames_per_batch: int, total_frames: int) -> Collector:
    """A synchronous collector: batches of shape (num_envs, frames_per_batch / num_envs)."""
    return Collector(
        env,
        policy,
        frames_per_batch=frames_per_batch,
        total_frames=total_frames,
        device="cpu",
        split_trajs=False,
        track_traj_ids=False,
        auto_register_policy_transforms=False,
    )


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


def carrier_state(collector: Collector) -> dict:
    """The collector's in-flight tensordict (current observations, episode sums) as plain data."""
    return collector._carrier.to_dict()


def restore_carrier(collector: Collector, state: dict) -> None:
    carrier = collector._carrier
    carrier.update(type(carrier).from_dict(state, batch_size=carrier.batch_size))
