"""Collection: TorchRL's Collector (resumable), bfc's fused collector that gives the same batches,
the collection the runner iterates (the env, its curriculum and a collector, here or in a worker
process) and per-batch episode statistics."""

from bfc.collectors.collection import AsyncCollection, LocalCollection, make_collection
from bfc.collectors.collector import episode_stats, make_collector
from bfc.collectors.fused import FusedCollector

__all__ = [
    "AsyncCollection",
    "FusedCollector",
    "LocalCollection",
    "episode_stats",
    "make_collection",
    "make_collector",
]


def __getattr__(name):
    if name == "ResumableCollector":  # TorchRL's collectors, imported on first use
        from bfc.collectors.torchrl_collector import ResumableCollector

        return ResumableCollector
    raise AttributeError(f"module 'bfc.collectors' has no attribute {name!r}")
