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


def _python(code: str) -> str:
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    root = Path(__file__).resolve().parents[1]
    r = subprocess.run([sys.executable, "-c", textwrap.dedent(code)], cwd=root, capture_output=True, text=True)
    assert r.returncode == 0, r.stderr[-2000:]
    return r.stdout.strip()


def test_training_imports_torchrl_without_ray_and_ray_still_imports_after():
    out = _python(
        """
        import sys
        from bfc.training import train
        from torchrl.data.replay_buffers import ray_buffer
        print("ray" in sys.modules, ray_buffer._has_ray)
        import ray
        print(ray.__name__, "ray" in sys.modules)
        """
    )
    assert out.splitlines() == ["False False", "ray True"]


def test_a_process_with_ray_loaded_keeps_torchrls_ray_pieces():
    out = _python(
        """
        import ray
        from bfc.training import train
        from torchrl.data.replay_buffers import ray_buffer
        print(ray_buffer._has_ray, ray_buffer.ray is ray)
        """
    )
    assert out == "True True"
