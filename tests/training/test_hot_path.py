"""The collection hot path's fast pieces give exactly what the TorchRL pieces they replace give."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from bfc import keys
from bfc.agent import GaussianActor, PolicySpec, SamplingActor, torchrl_actor
from bfc.config import compose
from bfc.factory import make_env


def assert_same(a: TensorDict, b: TensorDict) -> None:
    assert set(a.keys(True, True)) == set(b.keys(True, True))
    for key in a.keys(True, True):
        assert torch.equal(a.get(key), b.get(key)), key


@pytest.mark.parametrize("overrides", [[], ["extras=none", "noise.kind=ou"]])
def test_direct_partial_reset_equals_torchrl_reset(overrides):
    # short episodes, and half the drones with their motors off: they fall from their random
    # heights, crash at different steps and reset a few at a time
    cfg = compose(["env.episode_seconds=0.6", *overrides])
    rollouts = []
    for direct in (True, False):
        env = make_env(cfg, num_envs=12, seed=5)
        env.direct_reset = direct
        gen = torch.Generator().manual_seed(0)
        td, out, resets = env.reset(), [], 0
        for _ in range(150):
            action = torch.rand(12, 4, generator=gen) * 2 - 1
            action[:6] = -1.0
            td.set(keys.ACTION, action)
            step, td = env.step_and_maybe_reset(td)
            done = step.get(("next", keys.DONE))
            resets += int(done.any() and not done.all())
            out.append(step.clone())
        out.append(td.exclude(keys.ACTION).clone())  # the next step's root: where the resets landed
        rollouts.append(out)
        env.close()
    assert resets > 10
    for a, b in zip(*rollouts, strict=True):
        assert_same(a, b)


def test_sampling_actor_equals_the_probabilistic_actor():
    net = GaussianActor(25, [32, 32])
    actor = torchrl_actor(net)
    with torch.no_grad():
        net.log_std.copy_(torch.tensor([-1.0, -0.5, 0.0, 0.3]))
    fast = SamplingActor(net)
    obs = torch.randn(64, 25, generator=torch.Generator().manual_seed(1))
    for exploration in (ExplorationType.RANDOM, ExplorationType.DETERMINISTIC):
        outs = []
        for policy in (actor, fast):
            torch.manual_seed(7)
            with torch.no_grad(), set_exploration_type(exploration):
                outs.append(policy(TensorDict({keys.OBSERVATION: obs}, batch_size=[64])))
        assert_same(*outs)
        same_as_mean = torch.equal(outs[1].get(keys.ACTION), outs[1].get("loc"))
        assert same_as_mean == (exploration is ExplorationType.DETERMINISTIC)


def test_sampling_actor_shares_the_actors_weights(cfg):
    env = make_env(cfg, num_envs=4, seed=0)
    net = PolicySpec.from_config(cfg).make_net()
    actor, fast = torchrl_actor(net), SamplingActor(net)
    with torch.no_grad():
        net.mlp[0].weight.add_(1.0)  # an optimizer step on the actor
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        assert torch.equal(fast(td.clone()).get(keys.ACTION), actor(td.clone()).get(keys.ACTION))
    env.close()
