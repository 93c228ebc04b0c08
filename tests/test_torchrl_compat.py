"""bfc's reaches past TorchRL's public API (bfc/torchrl_compat.py) still find what they need."""

import torch
import torchrl
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer

from bfc.agent import PolicySpec
from bfc.collectors import make_collector
from bfc.config import compose
from bfc.factory import make_env
from bfc.torchrl_compat import (
    TORCHRL_VERSIONS,
    buffer_writer_state,
    collector_carrier,
    load_buffer_writer_state,
    load_collector_carrier,
)


def test_the_torchrl_version_is_the_one_the_reaches_were_written_for():
    assert torchrl.__version__.startswith(TORCHRL_VERSIONS), torchrl.__version__


def test_the_carrier_is_the_tensordict_the_next_step_starts_from():
    cfg = compose(["extras=none"])
    env = make_env(cfg, num_envs=4, seed=0)
    net = PolicySpec.from_config(cfg).make_net()
    collector = make_collector(env, net, frames_per_batch=8, total_frames=16)
    batch = next(iter(collector))
    carrier = collector_carrier(collector)
    # after the batch, the carrier holds the observation the last step ended in (or its reset)
    last_next = batch[:, -1].get(("next", "observation"))
    done = batch[:, -1].get(("next", "done")).squeeze(-1)
    assert torch.equal(carrier.get("observation")[~done], last_next[~done])
    saved = carrier.to_dict()
    carrier.set("observation", torch.zeros_like(carrier.get("observation")))
    load_collector_carrier(collector, saved)
    assert torch.equal(collector_carrier(collector).get("observation"), saved["observation"])
    collector.shutdown()
    env.close()


def test_the_replay_buffer_writer_state_says_where_the_next_transition_goes():
    buffer = TensorDictReplayBuffer(storage=LazyTensorStorage(4), batch_size=2)
    buffer.extend(TensorDict({"x": torch.arange(6.0)}, batch_size=[6]))  # wraps around: next write at 2
    state = buffer_writer_state(buffer)
    other = TensorDictReplayBuffer(storage=LazyTensorStorage(4), batch_size=2)
    other.extend(TensorDict({"x": torch.zeros(4)}, batch_size=[4]))
    load_buffer_writer_state(other, state)
    other.extend(TensorDict({"x": torch.tensor([9.0])}, batch_size=[1]))
    assert other.storage.get(2)["x"] == 9.0
