"""The flight loop: controllers flown from given starts in the batched env, never resetting mid-flight.

A crash (terminated) ends that flight as a failure: the physics goes on, but `alive` stays False.
`run_flights` (what training's evaluator uses) knows nothing of the classical controllers;
bfc.evaluation.flying.fly resolves a controller by name, path or module and flies it here.
"""

from __future__ import annotations

import time
import warnings
from contextlib import contextmanager

import torch
from tensordict import TensorDict
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from bfc import keys
from bfc.agent import SamplingActor, gaussian_net
from bfc.envs.quadrotor import FLAT_GOAL, state_views
from bfc.factory import find_transform
from bfc.transforms import GivenStarts, MotorSpeedAction
from bfc.transforms.pipeline import Pipeline, UnknownStage


def _given_starts(env: TransformedEnv) -> GivenStarts:
    starts = find_transform(env, GivenStarts)
    if starts is None:
        raise ValueError("the env has no GivenStarts transform: build it with make_flight_env or given_starts=True")
    return starts


@contextmanager
def one_torch_thread():
    """Flights run with one torch thread: MuJoCo's rollout threads own the cores (a second torch
    thread competes with them on 2 cores)."""
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


_RECORDED = (
    keys.ODOMETRY,
    keys.GOAL,
    keys.POSITION,
    keys.QUATERNION,
    keys.LINEAR_VELOCITY,
    keys.ANGULAR_VELOCITY,
    keys.MOTOR_SPEEDS,
)


@torch.no_grad()
def run_flights(
    env: TransformedEnv, policy, starts: torch.Tensor, steps: int, goal_schedule=None, torchrl: bool = False
) -> TensorDict:
    """Fly `policy` (deterministic) from `starts` (n, 12) for `steps` env steps.

    policy: a GaussianActor (or a TorchRL actor around one) on an env with the policy's maps, or
    a TensorDictModule controller reading `"odometry"` and `"goal"` and writing `"action"` (rad/s).
    goal_schedule: optional list of (step, goal (3,)) switching the goal in flight.
    Returns a TensorDict of shape (n, steps) with the ground truth, what the controller saw
    (`"odometry"`), the controller's `"action"` (motor speed commands, rad/s), `"goal"`, `"alive"`, `"time"` (s) and
    `"controller_seconds"` (wall-clock of the controller's call for the whole batch at that step).
    Flights run the env's pipeline (bfc.transforms.pipeline: the same stages TorchRL's `env.step`
    runs, on plain tensors), for any stack of bfc's transforms, latency and noise included;
    torchrl=True forces TorchRL's `env.step` (the reference the pipeline is tested against), as does
    a stack with a transform that is not bfc's (with a warning that says so).
    """
    base = env.base_env
    _given_starts(env).set_starts(starts.float())
    schedule = dict((int(s), g) for s, g in (goal_schedule or []))
    if 0 in schedule:
        base.set_goal(schedule[0])
    begin = getattr(policy, "begin_flight", None)
    if callable(begin):  # controllers with per-flight state (integrators, warm starts) forget it
        begin()
    pipeline = None if torchrl else _pipeline(env, policy)
    with set_exploration_type(ExplorationType.DETERMINISTIC), one_torch_thread():
        if pipeline is not None:
            out, seconds = fly_pipeline(pipeline, policy, steps, schedule)
        else:
            out, seconds = _torchrl_flight(env, policy, env.reset(), steps, schedule)
    n = base.num_envs
    out["time"] = torch.tensor([(t + 1) * base.dt for t in range(steps)]).expand(n, steps).clone()
    out["controller_seconds"] = torch.tensor(seconds).expand(n, steps).clone()
    return out


_SEEN = {keys.ODOMETRY, keys.GOAL}  # what a controller flown through the pipeline is given


def _pipeline(env: TransformedEnv, policy) -> Pipeline | None:
    """The env's pipeline, or None (with a warning saying why) where TorchRL's env.step must fly."""
    reads = set(getattr(policy, "in_keys", ())) if gaussian_net(policy) is None else set()
    if not reads <= _SEEN:
        warnings.warn(
            f"the controller reads {sorted(map(str, reads - _SEEN))}: it flies through TorchRL's env.step", stacklevel=3
        )
        return None
    try:
        return Pipeline.of(env)
    except UnknownStage as e:
        warnings.warn(f"{e} is not a bfc transform: this flight runs through TorchRL's env.step", stacklevel=3)
        return None


def _torchrl_flight(env: TransformedEnv, policy, td: TensorDict, steps: int, schedule: dict):
    """The reference loop: the controller through its TensorDict interface, TorchRL's `env.step`."""
    base, n = env.base_env, env.base_env.num_envs
    net = gaussian_net(policy)
    if net is not None:
        policy = SamplingActor(net)
    # A policy acts in its own [-1, 1] space: record every controller's command in rad/s.
    action_map = find_transform(env, MotorSpeedAction)
    to_rad_s = action_map.to_command if action_map is not None else (lambda a: a)
    alive = torch.ones(n, dtype=torch.bool)
    cols = {k: [] for k in (*_RECORDED, keys.ACTION, "alive")}
    seconds = []
    for t in range(steps):
        if t in schedule and t > 0:
            base.set_goal(schedule[t])
            td.set(keys.GOAL, base.goal)
        t0 = time.perf_counter()
        td = policy(td)
        seconds.append(time.perf_counter() - t0)
        command = to_rad_s(td.get(keys.ACTION)).clone()  # a controller may reuse its buffer
        td = env.step(td)
        nxt = td.get("next")
        alive = alive & ~nxt.get(keys.TERMINATED).reshape(n)
        for key in _RECORDED:  # the env writes a new buffer each step: kept as they are
            cols[key].append(nxt.get(key))
        cols[keys.ACTION].append(command)
        cols["alive"].append(alive)
        td = step_mdp(td)
    out = TensorDict({key: torch.stack(cols[key], 1) for key in cols}, batch_size=[n, steps])
    return out, seconds


def fly_pipeline(pipeline: Pipeline, policy, steps: int, schedule: dict | None = None, start=None):
    """Fly `steps` control steps through `pipeline` (any simulator's) from its envs' starts
    (`start` (n, 12), or what its samplers hold): bfc's actor's mean (the action map is a stage),
    or a controller's TensorDict call on the odometry it sees and the goal (rad/s). schedule:
    {step: goal}. (the flight's TensorDict without "time", the controller's seconds per step)."""
    n, schedule = pipeline.num_envs, schedule or {}
    net = gaussian_net(policy)
    state = pipeline.start(start)
    alive = torch.ones(n, dtype=torch.bool)
    flats, seen, commands, alives, seconds = [], [], [], [], []
    for t in range(steps):
        if t in schedule and t > 0:
            pipeline.physics.set_goal(state, schedule[t])
        t0 = time.perf_counter()
        if net is not None:
            state.action = net.mean(state.observation)
        else:
            td = TensorDict({keys.ODOMETRY: state.odometry, keys.GOAL: state.goal}, batch_size=[n])
            state.action, state.command = None, policy(td).get(keys.ACTION).clone()
        seconds.append(time.perf_counter() - t0)
        pipeline.step(state)
        alive = alive & ~state.terminated
        flats.append(state.truth)
        seen.append(state.odometry)
        commands.append(state.command)
        alives.append(alive)
    flat = torch.stack(flats, 1)
    out = TensorDict({keys.STATE: state_views(flat)}, batch_size=[n, steps])
    out.set(keys.ODOMETRY, torch.stack(seen, 1))
    out.set(keys.GOAL, flat[..., FLAT_GOAL])
    out.set(keys.ACTION, torch.stack(commands, 1))
    out.set("alive", torch.stack(alives, 1))
    return out, seconds
