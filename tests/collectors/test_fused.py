"""The fused collector as training runs it (its batches equal TorchRL's Collector's: tests/test_pipeline.py)."""

import pytest
import torch

from bfc.agent import PolicySpec
from bfc.collectors import make_collector
from bfc.config import compose
from bfc.factory import make_env


def test_the_collector_kind_is_checked_and_leaves_torchs_generator_alone():
    cfg = compose(["env.num_envs=4"])
    env = make_env(cfg, seed=0)
    net = PolicySpec.from_config(cfg).make_net()
    with pytest.raises(ValueError, match="collector.kind must be fused or torchrl, got 'ray'"):
        make_collector(env, net, 8, 8, kind="ray")
    for kind in ("fused", "torchrl"):
        torch.manual_seed(0)
        make_collector(env, net, 8, 8, kind=kind).shutdown()
        assert torch.equal(torch.get_rng_state(), torch.manual_seed(0).get_state())
    env.close()


def test_a_run_learns_the_same_through_either_collector(tmp_path):
    """Training through the fused collector is training through TorchRL's, bit for bit: the same
    weights, optimizer state and evaluations at the end."""
    from bfc.training import train
    from tests.training.helpers import TINY, compose_cfg

    runs = {}
    for kind in ("fused", "torchrl"):
        summary = train(compose_cfg([*TINY, f"collector.kind={kind}", "env.episode_seconds=0.3"]), tmp_path / kind)
        runs[kind] = (summary, torch.load(tmp_path / kind / "checkpoints" / "last.pt", weights_only=True))
    (a, ckpt_a), (b, ckpt_b) = runs["fused"], runs["torchrl"]
    for part in ("actor", "critic"):
        for key, value in ckpt_b[part].items():
            assert torch.equal(ckpt_a[part][key], value), (part, key)
    assert [h["eval/success_rate"] for h in a["history"]] == [h["eval/success_rate"] for h in b["history"]]
    assert torch.equal(ckpt_a["torch_rng"], ckpt_b["torch_rng"])


def test_a_worker_process_collects_while_the_learner_updates(tmp_path):
    """collector.workers=1: batches of the documented shape from the worker process, each flown
    one update behind (batches 0 and 1 with the initial weights, batch i with those after i - 1
    updates), a policy that loads and flies; the worker process is gone afterwards."""
    import copy
    import multiprocessing

    from bfc.evaluation import fly, protocol_starts
    from bfc.training.runner import Runner
    from tests.training.helpers import TINY, compose_cfg

    runner = Runner(compose_cfg([*TINY, "collector.kind=fused", "collector.workers=1"]), tmp_path)
    weights = [copy.deepcopy(runner.net)]  # weights[v]: after v updates
    for i, batch in enumerate(runner.collection):
        assert tuple(batch.batch_size) == (16, 32)
        flown = weights[max(0, i - 1)]
        with torch.no_grad():
            torch.testing.assert_close(batch.get("loc"), flown.mean(batch.get("observation")), rtol=0, atol=0)
        runner.learner.update(batch)
        runner.collection.update_policy_weights_()
        weights.append(copy.deepcopy(runner.net))
        if i == 3:
            break
    assert not torch.equal(weights[0].mlp[0].weight, weights[3].mlp[0].weight)  # it learned something
    runner.close()
    assert not [p for p in multiprocessing.active_children() if p.name.startswith("bfc-collector")]
    from bfc.training import train

    summary = train(compose_cfg([*TINY, "collector.kind=fused", "collector.workers=1"]), tmp_path / "run")
    assert summary["frames"] == 2048
    assert fly(tmp_path / "run" / "policy.pt", protocol_starts(2), seconds=0.2).shape == (2, 20)


def test_two_worker_processes_each_collect_half_of_the_envs():
    """collector.workers=2: a batch is the two workers' batches side by side, each from its own
    envs (its own seed), the same documented shape as one worker's."""
    from bfc.training.runner import Runner
    from tests.training.helpers import TINY, compose_cfg

    runner = Runner(compose_cfg([*TINY, "collector.workers=2"]), "/tmp/bfc-two-workers")
    try:
        batch = next(iter(runner.collection))
        assert tuple(batch.batch_size) == (16, 32)
        first, second = batch.get(("state", "position"))[:8, 0], batch.get(("state", "position"))[8:, 0]
        assert not torch.equal(first, second)  # two seeds, two sets of starts
        assert set(runner.collection.stats()) >= {"train/jd_probability", "train/physics_failures"}
    finally:
        runner.close()
