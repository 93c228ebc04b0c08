"""The flight loop: controllers flown from given starts in the batched env, never resetting mid-flight.

A crash (terminated) ends that flight as a failure: the physics goes on, but `alive` stays False.
`run_flights` (what training's evaluator uses) knows nothing of the classical controllers;
bfc.evaluation.flying.fly resolves a controller by name, path or module and flies it here.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import torch
from tensordict import TensorDict
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from bfc import keys
from bfc.agent import SamplingActor, gaussian_net
from bfc.envs.quadrotor import FLAT_GOAL, FLAT_ODOMETRY
from bfc.factory import find_transform
from bfc.transforms import GivenStarts, MotorSpeedAction, OdometryNoise, PolicyObservation


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
    env: TransformedEnv, policy, starts: torch.Tensor, steps: int, goal_schedule=None, lean: bool = True
) -> TensorDict:
    """Fly `policy` (deterministic) from `starts` (n, 12) for `steps` env steps.

    policy: a GaussianActor (or a TorchRL actor around one) on an env with the policy's maps, or
    a TensorDictModule controller reading `"odometry"` and `"goal"` and writing `"action"` (rad/s).
    goal_schedule: optional list of (step, goal (3,)) switching the goal in flight.
    Returns a TensorDict of shape (n, steps) with the ground truth, what the controller saw
    (`"odometry"`), the controller's `"action"` (motor speed commands, rad/s), `"goal"`, `"alive"`, `"time"` (s) and
    `"controller_seconds"` (wall-clock of the controller's call for the whole batch at that step).
    bfc's own actor flies through `_LeanFlight` (the same flights, without TorchRL's per-step
    plumbing); lean=False forces TorchRL's `env.step` (the reference the lean loop is tested against).
    """
    base = env.base_env
    _given_starts(env).set_starts(starts.float())
    schedule = dict((int(s), g) for s, g in (goal_schedule or []))
    if 0 in schedule:
        base.set_goal(schedule[0])
    begin = getattr(policy, "begin_flight", None)
    if callable(begin):  # controllers with per-flight state (integrators, warm starts) forget it
        begin()
    td = env.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC), one_torch_thread():
        flight = _LeanFlight.for_env(env, policy) if lean else None
        if flight is not None:
            out, seconds = flight.fly(td, steps, schedule)
        else:
            out, seconds = _torchrl_flight(env, policy, td, steps, schedule)
    n = base.num_envs
    out["time"] = torch.tensor([(t + 1) * base.dt for t in range(steps)]).expand(n, steps).clone()
    out["controller_seconds"] = torch.tensor(seconds).expand(n, steps).clone()
    return out


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


class _LeanFlight:
    """bfc's own deterministic actor flown as TorchRL's `env.step` flies it on an env whose
    transforms are GivenStarts, odometry noise (optional), PolicyObservation and MotorSpeedAction:
    per step the actor's mean, the action map to rad/s, the base env's `advance`, the noise's
    `corrupt`, the observation's `advance`, all on plain tensors; the outputs are packed once at
    the end. tests/evaluation/test_protocol.py checks the flights are TorchRL's bit for bit."""

    def __init__(self, env: TransformedEnv, net, observation, action_map, noise):
        self.base, self.net, self.observation, self.action_map, self.noise = (
            env.base_env,
            net,
            observation,
            action_map,
            noise,
        )

    @classmethod
    def for_env(cls, env: TransformedEnv, policy):
        net = gaussian_net(policy)
        noise = [t for t in env.transform if isinstance(t, OdometryNoise)]
        kinds = {type(t) for t in env.transform if not isinstance(t, OdometryNoise)}
        if net is None or len(noise) > 1 or kinds != {GivenStarts, PolicyObservation, MotorSpeedAction}:
            return None
        observation, action = find_transform(env, PolicyObservation), find_transform(env, MotorSpeedAction)
        return cls(env, net, observation, action, noise[0] if noise else None)

    def fly(self, td: TensorDict, steps: int, schedule: dict):
        base, n = self.base, self.base.num_envs
        obs = td.get(keys.OBSERVATION)
        alive = torch.ones(n, dtype=torch.bool)
        flats, seen, commands, alives, seconds = [], [], [], [], []
        for t in range(steps):
            if t in schedule and t > 0:
                base.set_goal(schedule[t])
            t0 = time.perf_counter()
            command = self.action_map.to_command(self.net.mean(obs))
            seconds.append(time.perf_counter() - t0)
            flat, terminated, _ = base.advance(command)
            odometry = flat[:, FLAT_ODOMETRY]
            if self.noise is not None:
                odometry = self.noise.corrupt(odometry)
            obs = self.observation.advance(command, odometry, flat[:, FLAT_GOAL])
            alive = alive & ~terminated
            flats.append(flat)
            seen.append(odometry)
            commands.append(command)
            alives.append(alive)
        none = torch.zeros(n, steps, dtype=torch.bool)
        packed = base.pack(torch.stack(flats, 1), none, none, reward=False)
        out = TensorDict({key: packed.get(key) for key in _RECORDED}, batch_size=[n, steps])
        out.set(keys.ODOMETRY, torch.stack(seen, 1))
        out.set(keys.ACTION, torch.stack(commands, 1))
        out.set("alive", torch.stack(alives, 1))
        return out, seconds
