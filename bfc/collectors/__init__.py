"""Building the TorchRL Collector over the env, and rollout/episode statistics."""

from bfc.collectors.collector import carrier_state, episode_stats, make_collector, restore_carrier

__all__ = ["carrier_state", "episode_stats", "make_collector", "restore_carrier"]
