"""The one pipeline (bfc.transforms.pipeline) against its references, over stacks and simulators:
training batches equal TorchRL's Collector's, flights equal TorchRL's `env.step`, and RotorPy's
physics stage flies the policy's maps as a hand-written loop over RotorPy's vehicle does, all bit
for bit; a stack with a transform that is not bfc's is refused by the collector and flown by
TorchRL's `env.step` with a warning."""

import importlib.util

import pytest
import torch
from torchrl.envs import RewardSum, StepCounter, TransformedEnv

from bfc import keys
from bfc.agent import PolicySpec
from bfc.collectors import FusedCollector, make_collector
from bfc.config import compose
from bfc.envs import AirframeParams
from bfc.evaluation import protocol_starts
from bfc.evaluation.flights import run_flights
from bfc.factory import make_env, make_flight_env
from bfc.transforms.pipeline import Pipeline, UnknownStage

HAVE_ROTORPY = all(importlib.util.find_spec(m) is not None for m in ("rotorpy", "torchdiffeq", "roma"))

# Stacks bfc's own config makes: the collector's (training) and the flights' (evaluation)
TRAINING_STACKS = [
    [],  # the default: JD at any attitude, CSS, TDTS (truncated), randomisation, the integral
    ["extras=none", "noise.kind=gaussian", "noise.std=0.02"],  # the paper's BFC, noise drawn at resets too
    ["extras=none", "noise.kind=ou", "tdts.as_terminal=true", "css.enabled=false"],
    ["+preset=paper", "+ablation=jd_tdts"],  # 250 Hz, odometry in, the speed map
    # late odometry and commands, drawn per env at each reset, beside biased noise
    ["latency.observation_steps=[0,3]", "latency.action_steps=[1,2]", "noise.kind=gaussian", "noise.bias=0.02"],
]
FLIGHT_STACKS = [
    (["model.position_integral=true"], {}),
    (["model.action_map=speed", "model.command_history=2"], {}),
    ([], {"noise": {"kind": "ou", "std": 0.05, "elements": "position"}}),
    (["model.position_integral=true"], {"observation_delay": 0.03, "action_delay": 0.02}),
    ([], {"observation_delay": 0.02, "noise": {"kind": "gaussian", "std": 0.02, "bias": 0.03}}),
]


def collect(kind: str, overrides, batches: int = 8, seed: int = 3):
    cfg = compose(["env.num_envs=24", "env.episode_seconds=0.2", *overrides])
    env = make_env(cfg, seed=seed)
    torch.manual_seed(seed)
    net = PolicySpec.from_config(cfg).make_net()
    with torch.no_grad():  # spread the actions: some drones crash, some hover to TDTS, episodes end all the time
        net.log_std.fill_(-0.5)
    fpb = 24 * 8
    collector = make_collector(env, net, fpb, fpb * batches, kind=kind)
    out = [b.clone() for b in collector]
    collector.shutdown()
    state = env.state_dict()
    env.close()
    return out, state


@pytest.mark.parametrize("overrides", TRAINING_STACKS)
def test_training_batches_through_the_pipeline_equal_torchrls_collectors(overrides):
    fused, fused_state = collect("fused", overrides)
    reference, reference_state = collect("torchrl", overrides)
    ends = 0
    for a, b in zip(fused, reference, strict=True):
        assert a.batch_size == b.batch_size
        assert set(a.keys(True, True)) == set(b.keys(True, True))
        for key in b.keys(True, True):
            assert a.get(key).dtype == b.get(key).dtype, key
            assert torch.equal(a.get(key), b.get(key)), key
        ends += int(b.get(("next", "done")).sum())
    assert ends > 20  # resets happened, inside batches and at their edges
    # and the env (physics, generators, every transform's buffers) ends in the same state
    assert fused_state.keys() == reference_state.keys()
    for key, value in reference_state.items():
        if isinstance(value, torch.Tensor):
            assert torch.equal(fused_state[key], value), key


def flight_env(overrides, flight, n=20):
    spec = PolicySpec.from_config(compose([*overrides, "model.actor_hidden=[32,32]"]))
    return spec, make_flight_env(n, policy=spec, physics_dt=0.01, seed=0, **flight)


def flight_starts(n=20):
    starts = protocol_starts(n, seed=3)
    starts[: n // 2, 3:5] = 0.0  # half level (they fly on), half tilted (most of them crash)
    return starts


@pytest.mark.parametrize(("overrides", "flight"), FLIGHT_STACKS)
def test_flights_through_the_pipeline_equal_torchrls_env_step(overrides, flight):
    """bfc's actor flies any stack of bfc's transforms through the pipeline (latency and noise
    included): the same flights as TorchRL's env.step, waypoints and crashes included."""
    spec, env = flight_env(overrides, flight)
    torch.manual_seed(0)
    actor = spec.make_net()  # commands about hover
    schedule = [(0, torch.tensor([0.0, 0.0, 1.5])), (40, torch.tensor([1.0, 0.0, 2.0]))]
    assert Pipeline.of(env) is not None  # no fallback: this stack is the pipeline's
    runs = {}
    for torchrl in (False, True):
        env.set_seed(0)
        runs[torchrl] = run_flights(env, actor, flight_starts(), 200, goal_schedule=schedule, torchrl=torchrl)
    piped, reference = runs[False], runs[True]
    assert (~piped["alive"][:, -1]).any() and piped["alive"][:, -1].any()  # some crashed, some flew
    for key in reference.keys(True, True):
        if key != "controller_seconds":
            assert torch.equal(piped.get(key), reference.get(key)), key
    env.close()


def test_a_classical_controller_flies_late_and_noisy_through_the_pipeline_as_through_torchrl():
    from bfc.controllers import CONTROLLERS

    env = make_flight_env(
        12, control_hz=100.0, physics_dt=0.01, seed=0, observation_delay=0.02, action_delay=0.01,
        noise={"kind": "gaussian", "std": 0.01},
    )  # fmt: skip
    runs = {}
    for torchrl in (False, True):
        lee = CONTROLLERS["lee"](AirframeParams(), 0.01)
        env.set_seed(0)
        runs[torchrl] = run_flights(env, lee, flight_starts(12), 150, torchrl=torchrl)
    for key in runs[False].keys(True, True):
        if key != "controller_seconds":
            assert torch.equal(runs[True].get(key), runs[False].get(key)), key
    assert runs[True]["alive"][:, -1].any()
    env.close()


def with_foreign_transform(env):
    from torchrl.envs import ObservationNorm

    env = TransformedEnv(env.base_env, env.transform.clone())
    env.append_transform(ObservationNorm(loc=0.0, scale=1.0, in_keys=["odometry"]))
    return env


def test_a_transform_that_is_not_bfcs_is_refused_by_the_collector_and_flown_by_torchrl_with_a_warning():
    cfg = compose(["env.num_envs=4"])
    env = with_foreign_transform(make_env(cfg, seed=0))
    with pytest.raises(ValueError, match="ObservationNorm needs collector.kind=torchrl"):
        FusedCollector(env, PolicySpec.from_config(cfg).make_net(), 8, 8)
    with pytest.raises(UnknownStage, match="ObservationNorm"):
        Pipeline.of(env)
    spec, flight = flight_env([], {}, n=4)
    flight = with_foreign_transform(flight)
    with pytest.warns(UserWarning, match="ObservationNorm is not a bfc transform: this flight runs through TorchRL"):
        out = run_flights(flight, spec.make_net(), flight_starts(4), 5)
    assert out.get(keys.POSITION).shape == (4, 5, 3)


def test_the_pipeline_runs_the_action_stages_before_the_physics_and_the_rest_in_the_stacks_order():
    cfg = compose(["env.num_envs=4", "latency.observation_steps=1", "latency.action_steps=1", "noise.kind=gaussian"])
    env = make_env(cfg, seed=0)
    statistics = (RewardSum, StepCounter)  # TorchRL's: the collector keeps them
    names = [type(s).__name__ for s in Pipeline.of(env, ignore=statistics).stages]
    assert names == [
        "MotorSpeedAction", "ActionDelay", "MuJoCoPhysics", "TimeDependentTerminalState", "JumpingDistribution",
        "ControlledStartingState", "GaussianOdometryNoise", "ObservationDelay", "PolicyObservation",
    ]  # fmt: skip
    env.close()


@pytest.mark.skipif(not HAVE_ROTORPY, reason='RotorPy is not installed: pip install -e ".[rotorpy]"')
@pytest.mark.parametrize("airframe", ["bfc", "rotorpy"])
def test_rotorpys_physics_stage_flies_the_policys_maps_as_a_loop_over_rotorpys_vehicle(airframe):
    """The second simulator behind the same stage contract: `fly_rotorpy` (the pipeline) equals the
    policy's maps and RotorPy's vehicle stepped by hand."""
    from bfc.agent import load_policy
    from bfc.evaluation.flights import one_torch_thread
    from bfc.evaluation.rotorpy_sim import RotorPyQuads, flight_params, fly_rotorpy

    spec, net = load_policy("pretrained/policy.pt")
    starts, n, dt, steps = flight_starts(6), 6, 1.0 / spec.control_hz, 60
    piped = fly_rotorpy("pretrained/policy.pt", starts, seconds=steps * dt, airframe=airframe)
    nominal = AirframeParams(**spec.airframe)
    quads = RotorPyQuads(flight_params(airframe, nominal, nominal), n, dt, airframe, None, nominal)
    quads.place(starts)
    observation, action_map = spec.make_observation_map(n, dt), spec.make_action_map()
    goal = torch.tensor([0.0, 0.0, 1.5]).expand(n, 3)
    with torch.no_grad(), one_torch_thread():  # as flights run: sums over one thread
        obs = observation.observe_restart(torch.ones(n, dtype=torch.bool), quads.odometry(), goal)
        for t in range(steps):
            command = action_map.to_command(net.mean(obs))
            quads.step(command)
            obs = observation.observe_step(command, quads.odometry(), goal)
            assert torch.equal(piped.get(keys.ACTION)[:, t], command)
            assert torch.equal(piped.get(keys.ODOMETRY)[:, t], quads.odometry())
            assert torch.equal(piped.get(keys.POSITION)[:, t], quads.state["x"].float())
            assert torch.equal(piped.get("alive")[:, t], quads.alive)


@pytest.mark.skipif(not HAVE_ROTORPY, reason='RotorPy is not installed: pip install -e ".[rotorpy]"')
def test_both_simulators_give_the_policy_the_same_first_observation():
    """One set of maps for both physics stages: placed at the same starts, MuJoCo and RotorPy hand
    the policy the same observation (to the float rounding of their attitude conversions)."""
    from bfc.agent import load_policy
    from bfc.evaluation.rotorpy_sim import RotorPyPhysics, RotorPyQuads, flight_params

    spec, _ = load_policy("pretrained/policy.pt")
    starts, n = flight_starts(8), 8
    env = make_flight_env(n, policy=spec, seed=0)
    env.transform[0].set_starts(starts)
    mujoco = Pipeline.of(env).start()
    nominal = AirframeParams(**spec.airframe)
    quads = RotorPyQuads(flight_params("bfc", nominal, nominal), n, 1.0 / spec.control_hz, "bfc", None, nominal)
    maps = [spec.make_observation_map(n), spec.make_action_map()]
    rotorpy = Pipeline(maps, RotorPyPhysics(quads, (0.0, 0.0, 1.5)), n).start(starts)
    torch.testing.assert_close(rotorpy.observation, mujoco.observation, atol=1e-5, rtol=1e-5)
    env.close()
