"""The paper preset's training pieces: each algorithm trains under it and writes a policy that
flies, the observation statistics travel in the policy file, Baselines' reward scaling, the
paper's reward, and a run paused and resumed (checkpoint.pause_at_frames) as one that was not."""

import json

import pytest
import torch

from bfc.agent import PolicySpec, load_policy, read_policy, save_policy
from bfc.agent.normalization import RewardScale
from bfc.config import validate
from bfc.training import train
from tests.evaluation.scripts import evaluate

from .helpers import TINY, compose_cfg

# the tiny run under a paper preset (which sets its own batch, epochs and minibatches)
PAPER_TINY = [*TINY, "loss.num_minibatches=4", "algo.ddpg.updates_per_batch=4"]


@pytest.mark.parametrize("preset", ["paper", "paper_trpo", "paper_ddpg"])
def test_each_algorithm_trains_under_its_paper_preset(tmp_path, preset):
    """A tiny run of each algorithm under its preset writes a policy file that carries the
    observation statistics it trained with; evaluate.py flies the PPO one."""
    cfg = compose_cfg([f"+preset={preset}", *PAPER_TINY])
    validate(cfg)
    summary = train(cfg, tmp_path)
    assert summary["frames"] == 2048 and not summary["paused"]
    policy = read_policy(tmp_path / "policy_last.pt")
    assert policy.spec.normalize_observation and policy.spec.observation == "odometry"
    assert float(policy.state_dict["obs_norm.count"]) == pytest.approx(2048, abs=1e-3)  # every collected frame
    assert float(policy.state_dict["obs_norm.var"][2]) != 1.0  # z: moved from its initial statistics
    if preset == "paper":
        r = evaluate(
            f"policy={tmp_path / 'policy.pt'}",
            "eval.num_starts=2",
            "eval.seconds=1",
            "figures=false",
            out=tmp_path / "eval",
        )
        assert r.returncode == 0, r.stderr[-2000:]
        assert json.loads((tmp_path / "eval" / "results.json").read_text())["starts"] == 2
    else:
        from bfc.evaluation import fly, protocol_starts

        flights = fly(str(tmp_path / "policy.pt"), protocol_starts(2, seed=0), seconds=0.2)
        assert flights.shape[0] == 2 and bool(torch.isfinite(flights.get(("state", "position"))).all())


def test_observation_statistics_make_the_policy_and_survive_a_round_trip(tmp_path):
    """A policy with running statistics flies the same after save and load; without its
    statistics it would command something else (they are part of what it is)."""
    from bfc.evaluation import fly, protocol_starts

    spec = PolicySpec(
        observation="odometry",
        action_map="speed",
        hidden=(16, 16),
        activation="tanh",
        normalize_observation=True,
        control_hz=250.0,
    )
    torch.manual_seed(0)
    net = spec.make_net()
    with torch.no_grad():
        net.mlp[-1].weight.normal_(0.0, 0.1)
        net.obs_norm.update(torch.randn(1000, 18) * torch.linspace(0.1, 3.0, 18) + 0.5)
    save_policy(tmp_path / "a.pt", spec, net)
    spec_b, net_b = load_policy(tmp_path / "a.pt")
    assert spec_b == spec
    for name in ("mean", "var", "count"):
        torch.testing.assert_close(getattr(net_b.obs_norm, name), getattr(net.obs_norm, name), rtol=0, atol=0)
    save_policy(tmp_path / "b.pt", spec_b, net_b)
    starts = protocol_starts(3, seed=0)
    a, b = (fly(str(tmp_path / f"{n}.pt"), starts, seconds=0.5) for n in "ab")
    torch.testing.assert_close(a.get(("state", "position")), b.get(("state", "position")), rtol=0, atol=0)
    obs = torch.randn(64, 18) * 2
    fresh = spec.make_net()
    fresh.load_state_dict({k: v for k, v in net.state_dict().items() if not k.startswith("obs_norm.")}, strict=False)
    assert not torch.allclose(fresh.mean(obs), net.mean(obs))


def test_reward_scale_divides_by_the_running_std_of_each_envs_discounted_return():
    """Baselines' VecNormalize(ret=True): ret <- gamma ret + r, reset after a done, rewards over
    sqrt(var(returns so far) + eps), clipped to +-10; its state carries a run on."""
    gamma, n, t = 0.9, 3, 5
    g = torch.Generator().manual_seed(0)
    batches = [(torch.randn(n, t, 1, generator=g), torch.rand(n, t, 1, generator=g) < 0.3) for _ in range(2)]
    scale = RewardScale(n, gamma)
    seen, ret = [], [0.0] * n
    for i, (reward, done) in enumerate(batches):
        for e in range(n):  # the recursion by hand, env by env
            for s in range(t):
                ret[e] = gamma * ret[e] + float(reward[e, s])
                seen.append(ret[e])
                if done[e, s]:
                    ret[e] = 0.0
        if i == 1:  # the second batch through a copy restored from the first's state
            restored = RewardScale(n, gamma)
            restored.load_state_dict(scale.state_dict())
            scale = restored
        got = scale(reward, done)
        var = torch.tensor(seen, dtype=torch.float64).var(correction=0)
        expected = (reward.double() / (var + 1e-8).sqrt()).clamp(-10, 10).float()
        torch.testing.assert_close(got, expected, rtol=2e-4, atol=1e-6)  # the prior's 1e-4 count
    calm = RewardScale(1, gamma)  # returns that barely varied so far: a unit reward is 1000 std
    calm.load_state_dict(
        {
            **calm.state_dict(),
            "var": torch.tensor(1e-6, dtype=torch.float64),
            "count": torch.tensor(1e9, dtype=torch.float64),
        }
    )
    assert calm(torch.ones(1, 2, 1), torch.zeros(1, 2, 1, dtype=torch.bool)).tolist() == [[[10.0], [10.0]]]


def test_the_papers_reward_is_position_and_angle_terms_and_a_crash_penalty():
    """reward=paper: -scale (position |p - g| + tilt (|roll| + |pitch|) + yaw |yaw|); a crash
    (leaving the box) adds -scale crash_penalty."""
    from bfc.envs import QuadrotorEnv, RewardParams

    weights = {"kind": "paper", "position": 1.0, "tilt": 0.5, "yaw": 0.1, "crash_penalty": 100.0, "scale": 0.01}
    env = QuadrotorEnv(3, control_hz=250.0, reward=weights, goal=(0.0, 0.0, 1.5), num_threads=1)
    start = torch.zeros(3, 12)
    start[:, 0:3] = torch.tensor([[1.0, 0.0, 1.5], [0.0, 0.5, 2.0], [4.999, 0.0, 1.5]])
    start[:, 3:6] = torch.tensor([[0.3, -0.2, 1.0], [0.0, 0.0, -2.5], [0.0, 0.0, 0.0]])
    start[2, 6] = 5.0  # flying out of the allowed box (|x| > 5 m)
    td = env.reset(env.reset().set("start_state", start))
    td["action"] = torch.full((3, 4), env.airframe.hover_speed)
    out = env.step(td)["next"]
    q, p = out.get(("state", "quaternion")), out.get(("state", "position"))
    w, x, y, z = q.unbind(-1)
    roll = torch.atan2(2 * (w * x + y * z), 1 - 2 * (x * x + y * y))
    pitch = torch.asin((2 * (w * y - z * x)).clamp(-1, 1))
    yaw = torch.atan2(2 * (w * z + x * y), 1 - 2 * (y * y + z * z))
    dist = (p - torch.tensor([0.0, 0.0, 1.5])).norm(dim=-1)
    expected = -0.01 * (dist + 0.5 * (roll.abs() + pitch.abs()) + 0.1 * yaw.abs())
    crashed = out["terminated"].squeeze(-1)
    assert crashed.tolist() == [False, False, True]
    expected = expected - 0.01 * 100.0 * crashed
    torch.testing.assert_close(out["reward"].squeeze(-1), expected, rtol=1e-5, atol=1e-6)
    with pytest.raises(ValueError, match="env.reward.kind must be bfc or paper"):
        RewardParams(kind="shaped")
    env.close()


def test_a_paused_run_resumes_to_the_same_weights_as_one_never_paused(tmp_path):
    """checkpoint.pause_at_frames ends the process with a checkpoint and a summary marked paused
    (here off the checkpoint and evaluation grid of 1,024 frames); the same command goes on to the
    end, bit for bit the run that never stopped: weights, observation statistics, the reward
    scale's state, the optimiser."""
    overrides = ["+preset=paper", *PAPER_TINY]
    straight = train(compose_cfg(overrides), tmp_path / "straight")
    paused = train(compose_cfg([*overrides, "checkpoint.pause_at_frames=1536"]), tmp_path / "staged")
    assert paused["paused"] and paused["frames"] == 1536
    assert read_policy(tmp_path / "staged" / "policy_last.pt").info["frames"] == 1536
    again = train(compose_cfg([*overrides, "checkpoint.pause_at_frames=1536"]), tmp_path / "staged")
    assert again["paused"] and again["frames"] == 1536  # nothing to do until the pause moves
    resumed = train(compose_cfg(overrides), tmp_path / "staged")
    assert not resumed["paused"] and resumed["frames"] == straight["frames"] == 2048
    assert resumed["resumed_from"] == [1536]
    a, b = (torch.load(tmp_path / d / "checkpoints" / "last.pt", weights_only=True) for d in ("straight", "staged"))
    for key in ("actor", "critic", "optimizer", "reward_scale"):
        assert key in a
    for part in ("actor", "critic"):
        for name, value in a[part].items():
            torch.testing.assert_close(value, b[part][name], rtol=0, atol=0, msg=f"{part}.{name}")
    for k in ("ret", "mean", "var", "count"):
        torch.testing.assert_close(a["reward_scale"][k], b["reward_scale"][k], rtol=0, atol=0)
    assert float(a["reward_scale"]["count"]) > 2048 - 1  # every step's return went in
    for sa, sb in zip(a["optimizer"]["state"].values(), b["optimizer"]["state"].values(), strict=True):
        torch.testing.assert_close(sa["exp_avg"], sb["exp_avg"], rtol=0, atol=0)


@pytest.mark.parametrize(
    ("override", "message"),
    [
        ("optim.adam_eps=0", "optim.adam_eps must be > 0"),
        ("loss.clip_value=-0.2", "loss.clip_value must be null (off) or > 0"),
        ("checkpoint.pause_at_frames=0", "checkpoint.pause_at_frames must be null (off) or > 0"),
    ],
)
def test_bad_values_of_the_new_keys_are_one_line(override, message):
    with pytest.raises(ValueError, match=message.replace("(", r"\(").replace(")", r"\)")):
        validate(compose_cfg([override]))


def test_a_paused_run_goes_on_to_a_new_pause_through_resume(tmp_path):
    """`train.py resume=<run> checkpoint.pause_at_frames=N` moves the pause of a paused run (the
    one key a resume takes from the command line; the rest is the run's own config)."""
    from tests.evaluation.scripts import run_script

    run = tmp_path / "run"
    train(compose_cfg([*TINY, "checkpoint.pause_at_frames=512"]), run)  # the run as `python train.py` writes it
    assert json.loads((run / "summary.json").read_text())["frames"] == 512
    r = run_script(
        "train.py",
        f"resume={run}",
        "checkpoint.pause_at_frames=1024",
        "collector.total_frames=99",
        out=tmp_path / "ignored",
    )
    assert r.returncode == 0, r.stderr[-2000:]
    summary = json.loads((run / "summary.json").read_text())
    assert summary["frames"] == 1024 and summary["paused"] and summary["resumed_from"] == [512]
