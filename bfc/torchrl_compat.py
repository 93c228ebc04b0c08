"""The one module that reaches past TorchRL's public API (written against torchrl 0.14), and
the one place that steers how TorchRL is imported.

bfc needs two things TorchRL keeps private:
- the Collector's in-flight tensordict (`Collector._carrier`): the observations, episode sums and
  step counts the next step starts from. A checkpoint that resumes bit-identically after a kill
  must hold it, and TorchRL's own `state_dict()` does not.
- a replay buffer's writer state (`ReplayBuffer._writer`): where the next transition goes. DDPG's
  checkpoint stores the filled part of its storage and this, not the whole preallocated storage
  that `ReplayBuffer.state_dict()` would write (1M transitions).
tests/test_torchrl_compat.py fails if a TorchRL upgrade moves either.

And one import-time cost: `torchrl.data` imports Ray whenever Ray is installed (for its Ray replay
buffer), about 0.3 s of every training launch, though bfc installs Ray for its sweeps only and
never uses TorchRL's Ray pieces (`import_torchrl_without_ray`).
"""

from __future__ import annotations

import importlib
import sys

from tensordict import TensorDictBase

from bfc.imports import without

TORCHRL_VERSIONS = "0.14"  # the versions these reaches were written and tested against


def collector_carrier(collector) -> TensorDictBase:
    """The tensordict TorchRL's Collector steps from next (updated in place as it collects)."""
    return collector._carrier


def load_collector_carrier(collector, state: dict) -> None:
    """Put a saved carrier (`collector_carrier(...).to_dict()`) back into a Collector."""
    carrier = collector._carrier
    carrier.update(type(carrier).from_dict(state, batch_size=carrier.batch_size))


def buffer_writer_state(buffer) -> dict:
    return buffer._writer.state_dict()


def load_buffer_writer_state(buffer, state: dict) -> None:
    buffer._writer.load_state_dict(state)


def import_torchrl_without_ray() -> None:
    """Import the TorchRL modules training uses with Ray hidden (`bfc.imports.without`), unless
    Ray (or TorchRL's data module) is loaded already: `find_spec("ray")`, TorchRL's check, then
    says "not installed", and afterwards Ray imports as usual (a sweep's launcher, a Ray job: those
    have it loaded first and are left alone). In this process TorchRL's Ray-backed classes then
    say Ray is missing; bfc uses none of them."""
    if "ray" in sys.modules or "torchrl.data" in sys.modules:
        return
    with without("ray"):
        for name in ("torchrl.data", "torchrl.envs", "torchrl.modules", "torchrl.objectives"):
            importlib.import_module(name)
