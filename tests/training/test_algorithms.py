"""The `algo` group: TRPO's KL-bounded step, DDPG's target networks, tiny runs of each that
`evaluate.py` flies, and the report's rows per algorithm."""

import json
import subprocess
import sys

import pytest
import torch
from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
from tensordict import TensorDict
from torch.distributions import Normal, kl_divergence

from bfc import keys
from bfc.agent import GaussianActor, load_policy, make_critic, torchrl_actor
from bfc.training import train
from bfc.training.trpo import TRPO, conjugate_gradient

from .helpers import ROOT, TINY, compose_cfg

ALGO_TINY = [
    "algo.ddpg.warmup_frames=512",
    "algo.ddpg.updates_per_batch=4",
    "algo.ddpg.batch_size=64",
    "algo.ddpg.buffer_size=4096",
]


def test_conjugate_gradient_solves_a_positive_definite_system():
    g = torch.Generator().manual_seed(0)
    m = torch.randn(12, 12, generator=g, dtype=torch.float64)
    a = m @ m.T + 12 * torch.eye(12, dtype=torch.float64)
    b = torch.randn(12, generator=g, dtype=torch.float64)
    x = conjugate_gradient(lambda v: a @ v, b, iterations=30)
    torch.testing.assert_close(a @ x, b, rtol=0, atol=1e-4)  # stops once |r|^2 < 1e-10


@pytest.mark.parametrize("max_kl", [0.001, 0.01, 0.05])
def test_trpo_step_stays_within_its_kl_bound_and_improves_the_surrogate(max_kl):
    """A small problem: 5 observations -> 4 actions, advantages that reward one direction of the
    action. Every step must keep the mean KL(old || new) <= max_kl, measured independently, and
    raise the surrogate; a larger bound must allow a larger move."""
    cfg = compose_cfg(["algo=trpo", f"algo.trpo.max_kl={max_kl}"])
    torch.manual_seed(0)
    actor = torchrl_actor(GaussianActor(5, [16], "tanh", 0.3))
    trpo = TRPO(cfg, actor, make_critic(5, [8]))
    head = trpo.net
    obs = torch.randn(2048, 5)
    moves = []
    for _ in range(3):
        with torch.no_grad():
            loc, scale = head(obs)
            old = Normal(loc, scale)
            action = old.sample()
            log_prob = old.log_prob(action).sum(-1)
            adv = (action[:, 0] - loc[:, 0]) + 0.5 * obs[:, 1] * (action[:, 1] - loc[:, 1])  # push a0 up, a1 with obs1
            adv = (adv - adv.mean()) / adv.std()
            before = (adv * 1.0).mean()  # ratio 1 at the old policy
        out = trpo.policy_step(obs, action, log_prob, adv)
        with torch.no_grad():
            new_loc, new_scale = head(obs)
            kl = kl_divergence(old, Normal(new_loc, new_scale)).sum(-1).mean().item()
            after = ((Normal(new_loc, new_scale).log_prob(action).sum(-1) - log_prob).exp() * adv).mean()
        assert out["loss/step_fraction"] > 0, "no step was accepted"
        assert kl <= max_kl * (1 + 1e-5) and out["loss/approx_kl"] == pytest.approx(kl, rel=1e-4)
        assert after > before
        moves.append(kl)
    assert max(moves) > 0.2 * max_kl  # it uses its budget, not a tiny step


def test_ddpg_target_networks_follow_with_tau():
    cfg = compose_cfg(["algo=ddpg", *TINY, *ALGO_TINY, "algo.ddpg.tau=0.1", "algo.ddpg.updates_per_batch=1"])
    from bfc.training.ddpg import DDPG

    torch.manual_seed(0)
    m = cfg.model
    net = GaussianActor(7, m.actor_hidden, m.activation, m.init_std, squash=m.squash)
    actor = torchrl_actor(net)
    ddpg = DDPG(cfg, actor, make_critic(7, m.critic_hidden, m.activation))
    loss = ddpg.loss_module
    n = 600
    data = TensorDict(
        {
            keys.OBSERVATION: torch.randn(n, 7),
            keys.ACTION: torch.rand(n, 4) * 2 - 1,
            "next": {
                keys.OBSERVATION: torch.randn(n, 7),
                keys.REWARD: torch.randn(n, 1),
                keys.DONE: torch.zeros(n, 1, dtype=torch.bool),
                keys.TERMINATED: torch.zeros(n, 1, dtype=torch.bool),
            },
        },
        batch_size=[n],
    )
    value_before = loss.target_value_network_params.clone()
    actor_before = loss.target_actor_network_params.clone()
    metrics = ddpg.update(data)
    assert set(metrics) == {"loss/actor", "loss/critic", "loss/q_value"} and ddpg.steps == 1
    for before, online, target in (
        (value_before, loss.value_network_params, loss.target_value_network_params),
        (actor_before, loss.actor_network_params, loss.target_actor_network_params),
    ):
        for key, old in before.items(True, True):
            expected = 0.9 * old + 0.1 * online.get(key).detach()
            torch.testing.assert_close(target.get(key), expected)
        assert any(not torch.equal(before.get(k), target.get(k)) for k in before.keys(True, True))
    # the exploration std is DDPG's fixed noise: not trained
    assert not net.log_std.requires_grad


@pytest.mark.parametrize("algo", ["trpo", "ddpg"])
@pytest.mark.parametrize("ablation", [None, "jd_css_tdts", "ppo"])
def test_tiny_run_of_each_algorithm_writes_tags_and_a_policy_evaluate_flies(algo, ablation, tmp_path):
    extra = [f"+ablation={ablation}"] if ablation else []
    cfg = compose_cfg([f"algo={algo}", *extra, *TINY, *ALGO_TINY, "env.episode_seconds=0.2"])
    if algo == "ddpg":
        assert cfg.model.squash and cfg.collector.frames_per_batch == 512  # TINY's batch wins over the group's
    summary = train(cfg, tmp_path / "run")
    assert summary["frames"] == 2048
    ea = EventAccumulator(str(tmp_path / "run" / "tb"))
    ea.Reload()
    tags = set(ea.Tags()["scalars"])
    assert {"loss/critic", "eval/success_rate", "train/episode_return", "time/fps"} <= tags
    assert ({"loss/objective", "loss/approx_kl"} if algo == "trpo" else {"loss/actor", "loss/q_value"}) <= tags
    spec, _ = load_policy(tmp_path / "run" / "policy.pt")
    assert spec.squash == (algo == "ddpg")
    if ablation == "ppo":  # one CLI evaluation per algorithm is enough
        r = subprocess.run(
            [
                sys.executable,
                "evaluate.py",
                f"policy={tmp_path / 'run' / 'policy.pt'}",
                "eval.num_starts=3",
                "eval.seconds=0.5",
                "eval.hold_seconds=0.2",
                "figures=false",
                f"hydra.run.dir={tmp_path / 'eval'}",
            ],
            cwd=ROOT,
            capture_output=True,
            text=True,
            timeout=300,
        )
        assert r.returncode == 0, r.stderr[-2000:]
        assert json.loads((tmp_path / "eval" / "results.json").read_text())["starts"] == 3


def test_ddpg_run_resumes_bit_identically(tmp_path):
    """The checkpoint carries DDPG's replay buffer, target networks and optimizers."""
    from .helpers import assert_same_checkpoint

    overrides = [
        "algo=ddpg",
        *TINY,
        *ALGO_TINY,
        "collector.total_frames=4096",
        "jd.decay_frames=4096",
        "optim.anneal_lr=false",
        "env.episode_seconds=0.2",
        "seed=2",
    ]
    train(compose_cfg(overrides), tmp_path / "full")
    train(compose_cfg([*overrides, "collector.total_frames=2048"]), tmp_path / "part")  # "killed"
    train(compose_cfg([*overrides, f"resume={tmp_path / 'part'}"]), tmp_path / "part")
    a = torch.load(tmp_path / "full" / "checkpoints" / "last.pt", weights_only=True)
    b = torch.load(tmp_path / "part" / "checkpoints" / "last.pt", weights_only=True)
    assert_same_checkpoint(a, b)
