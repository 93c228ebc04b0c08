"""The collection hot path's fast pieces give exactly what the TorchRL pieces they replace give."""

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from bfc import keys
from bfc.agent import GaussianActor, PolicySpec, SamplingActor, make_critic, torchrl_actor
from bfc.config import compose
from bfc.factory import make_env


def assert_same(a: TensorDict, b: TensorDict) -> None:
    assert set(a.keys(True, True)) == set(b.keys(True, True))
    for key in a.keys(True, True):
        assert torch.equal(a.get(key), b.get(key)), key


@pytest.mark.parametrize("overrides", [[], ["extras=none", "noise.kind=ou"]])
def test_fused_partial_reset_equals_torchrl_reset(overrides):
    # short episodes, and half the drones with their motors off: they fall from their random
    # heights, crash at different steps and reset a few at a time
    cfg = compose(["env.episode_seconds=0.6", *overrides])
    rollouts = []
    for fused in (True, False):
        env = make_env(cfg, num_envs=12, seed=5)
        env.fused_reset = fused
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


def _models(cfg, env):
    spec = PolicySpec.from_config(cfg)
    net = spec.make_net()
    critic = make_critic(spec.observation_size, cfg.model.critic_hidden, cfg.model.activation, net.obs_norm)
    return net, torchrl_actor(net, env.action_spec), critic


@pytest.mark.parametrize(
    ("entropy_coeff", "critic_loss", "clip_value"),
    [(0.0, "l2", None), (0.01, "l2", None), (0.0, "l1", None), (0.0, "smooth_l1", None), (0.0, "l2", 0.002)],
)
def test_fused_clip_loss_equals_clip_ppo_loss(cfg, entropy_coeff, critic_loss, clip_value):
    """The fused loss gives ClipPPOLoss's values bit for bit, and its gradients, on the same
    minibatch, for every critic loss the config names (loss.critic_loss), and with value clipping
    (loss.clip_value) and observation statistics (model.normalize_observation) as the paper preset
    trains them."""
    from bfc.training.advantage import compute_advantage
    from bfc.training.ppo import FusedClipLoss, make_loss

    cfg.loss.entropy_coeff, cfg.loss.critic_loss, cfg.loss.clip_value = entropy_coeff, critic_loss, clip_value
    cfg.model.normalize_observation = clip_value is not None
    env = make_env(cfg, num_envs=16, seed=0)
    net, actor, critic = _models(cfg, env)
    with torch.no_grad():
        net.log_std.copy_(torch.tensor([-1.5, -1.0, -2.0, -1.2]))
        data = env.rollout(40, actor, break_when_any_done=False)
        if net.obs_norm is not None:
            net.obs_norm.update(data["observation"])
        for p in [*actor.parameters(), *critic.parameters()]:  # both moved since the batch: ratios and values
            p.add_(0.05 * torch.randn_like(p))
    loss, advantage = make_loss(cfg, actor, critic)
    compute_advantage(data, advantage)
    flat = data.reshape(-1)
    with torch.no_grad():
        flat["state_value"] = flat["state_value"] + 0.01 * torch.randn_like(flat["state_value"])
    reference = loss(flat)
    fused = FusedClipLoss(loss, actor, critic)(
        flat["observation"],
        flat["action"],
        flat[loss.tensor_keys.sample_log_prob],
        flat["advantage"],
        flat["value_target"],
        flat["state_value"],
    )
    assert 0 < float(reference["clip_fraction"]) < 1
    if clip_value is not None:  # some values clipped, some not
        moved = (critic(flat.clone())["state_value"] - flat["state_value"]).abs()
        assert bool((moved > clip_value).any()) and bool((moved < clip_value).any())
    grads = []
    for out in (reference, fused):
        for key in ("loss_objective", "loss_critic", "entropy", "kl_approx", "clip_fraction"):
            torch.testing.assert_close(fused[key], reference[key], rtol=0, atol=0, msg=key)
        total = out["loss_objective"] + out["loss_critic"] + out.get("loss_entropy", 0.0)
        loss.zero_grad()
        total.backward()
        grads.append([p.grad.clone() for p in loss.parameters()])
    for a, b in zip(*grads, strict=True):
        torch.testing.assert_close(a, b, rtol=1e-5, atol=1e-9)  # the entropy term sums in another order
    env.close()


def test_the_fused_loss_refuses_what_it_does_not_compute(cfg):
    from torchrl.objectives import ClipPPOLoss

    from bfc.training.ppo import FusedClipLoss

    env = make_env(cfg, num_envs=2, seed=0)
    _, actor, critic = _models(cfg, env)
    loss = ClipPPOLoss(actor, critic, separate_losses=True, normalize_advantage=True)
    with pytest.raises(ValueError, match="does not implement ClipPPOLoss's separate_losses"):
        FusedClipLoss(loss, actor, critic)
    env.close()
