"""Building the TorchRL Collector over the env, and rollout/episode statistics."""

from bfc.collectors.collector import ResumableCollector, episode_stats, make_collector

__all__ = ["ResumableCollector", "episode_stats", "make_collector"]
