"""bfc's PPO step (its gradients written out) against TorchRL's ClipPPOLoss, autograd and torch's
Adam on the same minibatch: the same values and gradients to float rounding."""

import copy

import pytest
import torch
from torchrl.objectives import ClipPPOLoss

from bfc.agent import PolicySpec, make_critic, torchrl_actor
from bfc.config import compose
from bfc.factory import make_env
from bfc.training.advantage import compute_advantage
from bfc.training.mirror import make_mirrors
from bfc.training.ppo import PPO, make_loss
from bfc.training.ppo_step import PPOStep
from bfc.transforms.observation import cos_tilt

# The bound: each gradient within 1e-5 of its parameter's largest |gradient|. Not bit for bit: the
# surrogate's gradient is formed in one expression where autograd chains five, the entropy's is
# added in another order, and tanh is 2 sigmoid(2z) - 1 (torch's tanh to 2e-7).
RELATIVE = 1e-5

CASES = {
    "default": [],
    "paper": ["+preset=paper"],  # tanh, 2 x 256, observation statistics, value clipping
    "elu, smooth_l1, capped std": ["model.activation=elu", "loss.critic_loss=smooth_l1", "model.max_std=0.3"],
    "l1, no entropy, clipped value": ["loss.critic_loss=l1", "loss.entropy_coeff=0", "loss.clip_value=0.002"],
}


def _batch(overrides):
    """A minibatch the networks have moved away from since it was collected (ratios away from 1,
    some clipped; values away from the collected ones), with its ClipPPOLoss."""
    cfg = compose(overrides)
    env = make_env(cfg, num_envs=16, seed=0)
    spec = PolicySpec.from_config(cfg)
    net = spec.make_net()
    critic = make_critic(spec.observation_size, cfg.model.critic_hidden, cfg.model.activation, net.obs_norm)
    actor = torchrl_actor(net, env.action_spec)
    torch.manual_seed(0)
    with torch.no_grad():
        net.log_std.copy_(torch.tensor([-1.5, -1.0, -2.0, -1.2]))  # with max_std 0.3: one capped, one at the cap
        data = env.rollout(40, actor, break_when_any_done=False)
        if net.obs_norm is not None:
            net.obs_norm.update(data["observation"])
        for p in [*actor.parameters(), *critic.parameters()]:
            p.add_(0.02 * torch.randn_like(p))
    env.close()
    loss, advantage = make_loss(cfg, actor, critic)
    compute_advantage(data, advantage)
    flat = data.reshape(-1)
    with torch.no_grad():
        flat["state_value"] = flat["state_value"] + 0.01 * torch.randn_like(flat["state_value"])
    return cfg, net, actor, critic, loss, flat


def _columns(step, flat):
    old_value = [flat["state_value"]] if step.clip_value is not None else []
    obs = step.observe(flat["observation"])
    return obs, flat["action"], flat["action_log_prob"], flat["advantage"], flat["value_target"], *old_value


def _assert_gradients(step, expected):
    """Each parameter's slot of the step's flat gradient against `expected` (id -> gradient)."""
    start = 0
    for p in step.params:
        grad = step.flat.grad[start : start + p.numel()].view_as(p)
        want = expected[id(p)]
        assert (grad - want).abs().max() <= RELATIVE * want.abs().max(), tuple(p.shape)
        start += p.numel()


@pytest.mark.parametrize("case", CASES)
def test_the_step_gives_clip_ppo_losss_values_and_gradients(case):
    cfg, _, actor, critic, loss, flat = _batch(CASES[case])
    reference = loss(flat)
    assert 0 < float(reference["clip_fraction"]) < 1
    total = reference["loss_objective"] + reference["loss_critic"] + reference.get("loss_entropy", 0.0)
    loss.zero_grad()
    total.backward()
    expected = {id(p): p.grad.clone() for p in loss.parameters()}
    before = [p.detach().clone() for p in loss.parameters()]

    step = PPOStep(loss, actor, critic, lr=0.0, adam_eps=1e-8, max_grad_norm=1e9)  # lr 0: read the gradient
    assert all(torch.equal(a, p) for a, p in zip(before, loss.parameters(), strict=True))  # moved, not changed
    metrics = dict(zip(PPOStep.METRICS, step(*_columns(step, flat)), strict=True))
    assert float(metrics.pop("mirror")) == 0.0  # no mirrors, no mirror loss
    for key, value in metrics.items():
        torch.testing.assert_close(value, reference[key].detach().reshape(()), rtol=1e-5, atol=1e-7, msg=key)
    _assert_gradients(step, expected)


@pytest.mark.parametrize(
    "overrides",
    [
        ["env.airframe=x500", "loss.mirror_coeff=2"],  # both mirrors and the half turn, bfc's observation
        ["env.airframe=crazyflie", "+preset=paper", "loss.mirror_coeff=0.5"],  # the paper's, statistics, tanh
        ["loss.mirror_coeff=1", "model.squash=true"],  # a "+": the half turn only, a squashed mean
        ["env.airframe=x500", "loss.mirror_coeff=2", "loss.mirror_reflections=one"],  # one mirror a row
    ],
)
def test_the_step_with_mirrors_gives_autograds_gradients_of_the_mirror_loss_too(overrides):
    """With `loss.mirror_coeff` the step adds the mirror loss (bfc.training.mirror) in the actor's
    pass: its value and every gradient as autograd gives them for ClipPPOLoss plus that loss."""
    cfg, net, actor, critic, loss, flat = _batch(overrides)
    mirrors = make_mirrors(cfg)
    reflection = mirrors.reflection(torch.arange(flat.numel()))
    seen = mirrors.observations(flat["observation"], reflection)
    reference = loss(flat)
    mirror, _ = mirrors.loss(net.mean(flat["observation"]), net.mean(seen), reflection)
    assert float(mirror.detach()) > 0
    total = reference["loss_objective"] + reference["loss_critic"] + reference.get("loss_entropy", 0.0) + mirror
    loss.zero_grad()
    total.backward()
    expected = {id(p): p.grad.clone() for p in loss.parameters()}
    step = PPOStep(loss, actor, critic, lr=0.0, adam_eps=1e-8, max_grad_norm=1e9, mirrors=mirrors)
    metrics = dict(
        zip(
            PPOStep.METRICS,
            step(*_columns(step, flat), mirrored=step.observe(seen), reflection=reflection),
            strict=True,
        )
    )
    torch.testing.assert_close(metrics["mirror"], mirror.detach(), rtol=1e-5, atol=1e-8)
    _assert_gradients(step, expected)


def test_the_mirror_loss_holds_only_the_rows_within_mirror_max_tilt():
    """`loss.mirror_max_tilt`: a row tilted more than it from upright adds nothing to the mirror loss
    (value or gradient), a row within it what it adds without the bound; the step's gradients are
    still autograd's."""
    cfg, net, actor, critic, loss, flat = _batch(["env.airframe=x500", "loss.mirror_coeff=2"])
    obs = flat["observation"]
    tilt = torch.rad2deg(torch.acos(cos_tilt(obs, cfg.model.observation).clamp(-1, 1)))
    bound = float(tilt.median())  # half the rows each side
    free = make_mirrors(cfg)  # every row (the default 180)
    assert free.kept(obs) is None
    cfg.loss.mirror_max_tilt = bound
    bounded = make_mirrors(cfg)
    kept = bounded.kept(obs)
    assert torch.equal(kept.bool(), tilt <= bound) and 0 < int(kept.sum()) < len(kept)
    seen = free.observations(obs)
    each = [free.loss(net.mean(obs[i : i + 1]), net.mean(seen[:, i : i + 1]))[0] for i in range(len(obs))]
    mirror, _ = bounded.loss(net.mean(obs), net.mean(seen), None, kept)
    torch.testing.assert_close(mirror, torch.stack(each)[kept.bool()].sum() / len(obs), rtol=1e-5, atol=1e-9)
    reference = loss(flat)
    total = reference["loss_objective"] + reference["loss_critic"] + reference.get("loss_entropy", 0.0) + mirror
    loss.zero_grad()
    total.backward()
    expected = {id(p): p.grad.clone() for p in loss.parameters()}
    step = PPOStep(loss, actor, critic, lr=0.0, adam_eps=1e-8, max_grad_norm=1e9, mirrors=bounded)
    step(*_columns(step, flat), mirrored=step.observe(seen), kept=kept)
    _assert_gradients(step, expected)


def test_a_step_moves_the_weights_as_torchs_adam_after_clipping():
    """One step at the default's rate and clipping: the weights land where torch's Adam puts them
    with ClipPPOLoss's gradients clipped by clip_grad_norm_."""
    cfg, _, actor, critic, loss, flat = _batch([])
    params = list(loss.parameters())
    reference = [p.detach().clone().requires_grad_() for p in params]
    out = loss(flat)
    total = out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]
    grads = torch.autograd.grad(total, params)
    for r, g in zip(reference, grads, strict=True):
        r.grad = g.clone()
    norm = torch.nn.utils.clip_grad_norm_(reference, 0.05)
    assert norm > 0.05  # the clipping acts
    torch.optim.Adam(reference, lr=1e-3, eps=1e-8).step()

    step = PPOStep(loss, actor, critic, lr=1e-3, adam_eps=1e-8, max_grad_norm=0.05)
    step(*_columns(step, flat))
    for p, r in zip(params, reference, strict=True):
        torch.testing.assert_close(p.detach(), r.detach(), rtol=0, atol=1e-6)


def test_the_parameters_stay_the_networks_and_the_flat_buffers_views():
    """After the step is built the actor and critic still hold their Parameters (the collector,
    the policy file and ClipPPOLoss see the trained weights), now views of one buffer."""
    _, net, actor, critic, loss, flat = _batch([])
    objects = [id(p) for p in net.parameters()]
    step = PPOStep(loss, actor, critic, lr=1e-3, adam_eps=1e-8, max_grad_norm=1.0)
    assert [id(p) for p in net.parameters()] == objects
    before = net.mlp[0].weight.detach().clone()
    step(*_columns(step, flat))
    assert not torch.equal(net.mlp[0].weight, before)
    assert net.mlp[0].weight.data_ptr() >= step.flat.data_ptr()
    state = net.state_dict()
    assert torch.equal(state["mlp.0.weight"], net.mlp[0].weight)


def test_an_optimizer_state_from_before_loads_into_the_flat_adam():
    """A checkpoint written by torch's Adam over the parameters one by one (before this step)
    resumes: its moments, concatenated in the loss module's order, and its step count."""
    cfg, _, actor, critic, loss, flat = _batch([])
    params = list(loss.parameters())
    old = torch.optim.Adam(params, lr=1e-3)
    for p in params:
        p.grad = torch.randn_like(p)
    old.step()
    state = old.state_dict()
    step = PPOStep(loss, actor, critic, lr=1e-3, adam_eps=1e-8, max_grad_norm=1.0)
    step.load_state_dict(state)
    loaded = step.optimizer.state[step.flat]
    assert float(loaded["step"]) == 1.0
    assert torch.equal(loaded["exp_avg"], torch.cat([old.state[p]["exp_avg"].reshape(-1) for p in params]))
    assert torch.equal(loaded["exp_avg_sq"], torch.cat([old.state[p]["exp_avg_sq"].reshape(-1) for p in params]))


def test_what_the_step_does_not_compute_is_refused_naming_torchrls_loss():
    cfg, net, actor, critic, _, _ = _batch([])
    separate = ClipPPOLoss(actor, critic, separate_losses=True, normalize_advantage=True)
    with pytest.raises(ValueError, match="separate_losses; use loss.implementation=torchrl"):
        PPOStep(separate, actor, critic, 1e-3, 1e-8, 1.0)
    net.mlp[1] = torch.nn.Sigmoid()  # an activation it has no backward for
    with pytest.raises(ValueError, match="tanh, relu or elu; use loss.implementation=torchrl"):
        PPOStep(ClipPPOLoss(actor, critic, normalize_advantage=True), actor, critic, 1e-3, 1e-8, 1.0)


@pytest.mark.parametrize("implementation", ["bfc", "torchrl"])
def test_both_implementations_update_and_report_the_same_metrics(implementation):
    """`loss.implementation` picks the step; both train the networks and log the same tags."""
    cfg, net, actor, critic, _, flat = _batch([f"loss.implementation={implementation}"])
    learner = PPO(cfg, actor, critic)
    assert (learner.step is not None) == (implementation == "bfc")
    before = net.mlp[0].weight.detach().clone()
    data = flat.exclude("advantage", "value_target").reshape(16, -1)
    metrics = learner.update(data)
    assert set(metrics) == {"loss/objective", "loss/critic", "loss/entropy", "loss/approx_kl", "loss/clip_fraction"}
    assert all(torch.isfinite(torch.tensor(v)) for v in metrics.values())
    assert not torch.equal(net.mlp[0].weight, before)


@pytest.mark.parametrize("reflections, max_tilt", [("all", 180), ("one", 180), ("all", 60)])
def test_both_implementations_take_the_same_update_with_the_mirror_loss(reflections, max_tilt):
    """A whole PPO.update with mirrors (the batch's mirrored columns, their minibatches, each row's
    reflection, the rows `loss.mirror_max_tilt` keeps): bfc's step and TorchRL's loss plus the
    mirror term under autograd end at the same weights."""
    overrides = ["env.airframe=x500", "loss.mirror_coeff=2", f"loss.mirror_reflections={reflections}"]
    overrides.append(f"loss.mirror_max_tilt={max_tilt}")
    overrides.append("loss.mirror_from_frames=0")  # the X500's built-in waits for 1M frames
    cfg, _, actor, critic, _, flat = _batch(overrides)
    kept = make_mirrors(cfg).kept(flat["observation"])
    assert kept is None if max_tilt == 180 else 0 < int(kept.sum()) < len(kept)  # rows on both sides of it
    data = flat.exclude("advantage", "value_target").reshape(16, -1)
    weights, logged = [], []
    for implementation in ("bfc", "torchrl"):
        cfg.loss.implementation = implementation
        mine, its_critic = copy.deepcopy(actor), copy.deepcopy(critic)
        torch.manual_seed(5)  # the same minibatches
        metrics = PPO(cfg, mine, its_critic).update(data.clone())
        weights.append(torch.cat([p.detach().reshape(-1) for p in [*mine.parameters(), *its_critic.parameters()]]))
        logged.append(metrics["loss/mirror"])
    torch.testing.assert_close(weights[0], weights[1], rtol=0, atol=1e-5)
    assert logged[0] == pytest.approx(logged[1], rel=1e-4) and logged[0] > 0


def test_the_update_adds_the_mirror_loss_from_mirror_from_frames():
    """Before `loss.mirror_from_frames` an update is the one without mirrors, weight for weight."""
    cfg, _, actor, critic, _, flat = _batch(["env.airframe=x500", "loss.mirror_from_frames=1000"])
    data = flat.exclude("advantage", "value_target").reshape(16, -1)

    def update(coeff, frames):
        cfg.loss.mirror_coeff = coeff
        mine, its_critic = copy.deepcopy(actor), copy.deepcopy(critic)
        torch.manual_seed(5)
        metrics = PPO(cfg, mine, its_critic).update(data.clone(), frames=frames)
        return torch.cat([p.detach().reshape(-1) for p in [*mine.parameters(), *its_critic.parameters()]]), metrics

    plain, _ = update(0.0, 999)
    before, logged_before = update(2.0, 999)
    after, logged_after = update(2.0, 1000)
    assert torch.equal(before, plain) and "loss/mirror" not in logged_before
    assert logged_after["loss/mirror"] > 0 and (after - plain).abs().max() > 1e-4
