"""Fly controllers from given starts in the batched env, never resetting mid-flight.

A crash (terminated) ends that flight as a failure: the physics goes on, but `alive` stays False.
The flight loop (`run_flights`, what training's evaluator uses) knows nothing of the classical
controllers: `fly` imports them only when it is asked to fly one by name.
"""

from __future__ import annotations

import time
from contextlib import contextmanager

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict
from tensordict.nn import TensorDictModuleBase
from torchrl.envs import TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from bfc import keys
from bfc.envs import REFERENCE_PHYSICS_DT, AirframeParams
from bfc.factory import find_transform, make_env
from bfc.transforms import GivenStarts, MotorSpeedAction


def _given_starts(env: TransformedEnv) -> GivenStarts:
    starts = find_transform(env, GivenStarts)
    if starts is None:
        raise ValueError("the env has no GivenStarts transform: build it with make_env(..., given_starts=True)")
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

    goal_schedule: optional list of (step, goal (3,)) switching the goal in flight.
    Returns a TensorDict of shape (n, steps) with the ground truth, what the controller saw
    (`"odometry"`), the controller's `"action"` (motor speed commands, rad/s), `"goal"`, `"alive"`, `"time"` (s) and
    `"controller_seconds"` (wall-clock of the controller's call for the whole batch at that step).
    bfc's own actor on an env whose only transforms are the starts and the policy's maps flies
    through `_LeanSteps` (the same flights, without TorchRL's per-step plumbing); lean=False
    forces TorchRL's `env.step` (the reference the lean loop is tested against).
    """
    base = env.base_env
    _given_starts(env).set_starts(starts.float())
    schedule = dict((int(s), g) for s, g in (goal_schedule or []))
    if 0 in schedule:
        base.set_goal(schedule[0])
    begin = getattr(policy, "begin_flight", None)
    if callable(begin):  # controllers with per-flight state (integrators, warm starts) forget it
        begin()
    # A policy acts in its own [-1, 1] space: record every controller's command in rad/s.
    action_map = find_transform(env, MotorSpeedAction)
    to_rad_s = action_map.to_command if action_map is not None else (lambda a: a)
    td = env.reset()
    n = base.num_envs
    stepper = _LeanSteps.for_env(env, policy) if lean else None
    policy = fast_policy(policy)
    alive = torch.ones(n, dtype=torch.bool)
    cols = {k: [] for k in (*_RECORDED, keys.ACTION, "alive", "controller_seconds")}
    with set_exploration_type(ExplorationType.DETERMINISTIC), one_torch_thread():
        for t in range(steps):
            if t in schedule and t > 0:
                base.set_goal(schedule[t])
                td.set(keys.GOAL, base.goal)
            t0 = time.perf_counter()
            if stepper is not None:
                command = stepper.act(td)
                cols["controller_seconds"].append(time.perf_counter() - t0)
                nxt = stepper.step(command)
            else:
                td = policy(td)
                cols["controller_seconds"].append(time.perf_counter() - t0)
                command = to_rad_s(td.get(keys.ACTION)).clone()  # a controller may reuse its buffer
                td = env.step(td)
                nxt = td.get("next")
            alive = alive & ~nxt.get(keys.TERMINATED).reshape(n)
            # the env writes a new buffer each step, so the step's tensors are kept as they are
            for key in _RECORDED:
                cols[key].append(nxt.get(key))
            cols[keys.ACTION].append(command)
            cols["alive"].append(alive)
            td = nxt if stepper is not None else env._step_mdp(td)
    out = TensorDict(
        {key: torch.stack(cols[key], 1) for key in (*_RECORDED, keys.ACTION, "alive")}, batch_size=[n, steps]
    )
    out["time"] = torch.tensor([(t + 1) * base.dt for t in range(steps)]).expand(n, steps).clone()
    out["controller_seconds"] = torch.tensor(cols["controller_seconds"]).expand(n, steps).clone()
    return out


class _LeanSteps:
    """One control step of bfc's own deterministic actor, as TorchRL's `env.step` runs it on an
    env whose transforms are GivenStarts, PolicyObservation and MotorSpeedAction only: the
    actor's mean, the action map to rad/s, the base env's step, then the observation's step (the
    only transform with per-step work). tests/evaluation/test_protocol.py checks the flights are
    TorchRL's bit for bit (bench/eval_time.py compares the two paths' wall-clock)."""

    def __init__(self, env: TransformedEnv, head, observation, action_map):
        self.base, self.head, self.observation, self.action_map = env.base_env, head, observation, action_map

    @classmethod
    def for_env(cls, env: TransformedEnv, policy):
        from bfc.policy import is_gaussian_actor
        from bfc.transforms import PolicyObservation

        kinds = {type(t) for t in env.transform}
        if not is_gaussian_actor(policy) or kinds != {GivenStarts, PolicyObservation, MotorSpeedAction}:
            return None
        return cls(
            env, policy.module[0].module, find_transform(env, PolicyObservation), find_transform(env, MotorSpeedAction)
        )

    def act(self, td: TensorDict) -> torch.Tensor:
        loc, _ = self.head(td.get(keys.OBSERVATION))
        return self.action_map.to_command(loc)

    def step(self, command: torch.Tensor) -> TensorDict:
        request = TensorDict({keys.ACTION: command}, batch_size=self.base.batch_size)
        return self.observation._step(request, self.base._step(request))


def fast_policy(policy):
    """bfc's own actor flown through `SamplingActor` (the same actions, without the
    ProbabilisticActor's per-call overhead); any other controller as it is."""
    from bfc.policy import SamplingActor, is_gaussian_actor

    return SamplingActor(policy) if is_gaussian_actor(policy) else policy


def config_for(env_settings: dict | None = None, **sections):
    """A full config (defaults) with the given `env` settings and sections merged in. A policy
    file's training-time randomisation is left out: flights never randomise (and files of older
    releases carry randomisation keys this one no longer has)."""
    from bfc.config import Config

    cfg = OmegaConf.structured(Config)
    if env_settings:
        cfg.env = OmegaConf.merge(cfg.env, {k: v for k, v in env_settings.items() if k != "randomize"})
    for name, value in sections.items():
        cfg[name] = OmegaConf.merge(cfg[name], value)
    return cfg


def is_module(controller) -> bool:
    return isinstance(controller, (TensorDictModuleBase, torch.nn.Module))


def _goal_schedule(goal, dt: float):
    """`goal` as (3,) or as [(time_s, (x, y, z)), ...]: -> (first goal, [(step, goal), ...])."""
    g = list(goal)
    if len(g) == 3 and all(isinstance(v, (int, float)) for v in g):
        return torch.tensor(g, dtype=torch.float32), None
    try:
        sched = [(round(float(t) / dt), torch.tensor([float(v) for v in xyz])) for t, xyz in g]
    except (TypeError, ValueError):
        raise ValueError("goal must be (x, y, z) or a list of (time_seconds, (x, y, z)) waypoints") from None
    if not sched or sched[0][0] != 0 or any(w.shape != (3,) for _, w in sched):
        raise ValueError("a waypoint schedule must start at time 0 and give (x, y, z) for each waypoint")
    return sched[0][1], sched


PROTOCOL_HZ = 250.0  # the paper's control rate, for controllers that do not record their own


def fly(
    controller,
    starts,
    goal=(0.0, 0.0, 1.5),
    seconds: float = 10.0,
    noise=None,
    seed: int = 0,
    control_hz=None,
    airframe: dict | None = None,
    external_force=None,
    physics_dt: float = REFERENCE_PHYSICS_DT,
) -> TensorDict:
    """Fly all `starts` (n, 12) at once for `seconds`, never resetting mid-flight.

    controller: a policy.pt path (always flown at the control rate it was trained at), a
    controller name registered in `CONTROLLERS`, or a TensorDictModule reading `"odometry"`/`"goal"`
    and writing `"action"` in rad/s (flown at `control_hz`, default 250 Hz as in the paper).
    goal: (x, y, z) or waypoints [(time_s, (x, y, z)), ...]. noise: a `noise` config section, e.g.
    {"kind": "ou", "std": 0.05, "elements": "position"}; it corrupts only what the controller sees.
    airframe: AirframeParams fields of the flown body, e.g. {"body_mass": 0.884} (model mismatch):
    a classical controller keeps the nominal model it was built for, a policy its own maps.
    external_force: a constant force in newtons, world frame, (3,) or one per start (n, 3).
    physics_dt: MuJoCo's step, the reference 0.002 s by default, whatever step a policy was
    trained with (its control rate is its own).
    Returns a TensorDict (n, T); see `run_flights`.
    """
    from bfc.controllers import CONTROLLERS
    from bfc.policy import load_policy, model_settings

    starts = torch.as_tensor(starts, dtype=torch.float32)
    if starts.ndim != 2 or starts.shape[1] != 12:
        raise ValueError(f"starts must have shape (n, 12), got {tuple(starts.shape)}")
    if seconds <= 0:
        raise ValueError(f"seconds must be > 0, got {seconds}")
    if isinstance(controller, (str, bytes)) and str(controller) in CONTROLLERS:
        name, settings, policy_io, model = str(controller), None, False, {}
    elif is_module(controller):
        name, settings, policy_io, model = None, None, False, {}
    elif isinstance(controller, (str, bytes)) or hasattr(controller, "__fspath__"):
        name = None
        controller, payload = load_policy(controller)
        settings, policy_io = payload["env"], True
        model = model_settings(payload)  # flown with the observation and action maps it was trained with
    else:
        allowed = f"a policy.pt path, one of {sorted(CONTROLLERS)} or a TensorDictModule"
        raise ValueError(f"controller must be {allowed}, got {controller!r}")
    cfg = config_for(settings, noise=noise or {"kind": "none"}, model=model)
    if settings is None:
        cfg.env.control_hz = float(control_hz or PROTOCOL_HZ)
    elif control_hz is not None and float(control_hz) != float(settings["control_hz"]):
        raise ValueError(f"this policy was trained at {settings['control_hz']} Hz and is flown at that rate only")
    cfg.env.episode_seconds = seconds + 1.0
    cfg.env.physics_dt = float(physics_dt)
    n = starts.shape[0]
    env = make_env(cfg, num_envs=n, samplers=False, given_starts=True, policy_io=policy_io, airframe=airframe)
    env.set_seed(seed)
    try:
        if external_force is not None:
            env.base_env.set_external_force(external_force)
        if name is not None:  # built for the nominal airframe, whatever body it flies
            nominal = AirframeParams(**OmegaConf.to_container(cfg.env.airframe))
            controller = CONTROLLERS[name](nominal, env.base_env.dt)
        first, schedule = _goal_schedule(goal, env.base_env.dt)
        env.base_env.set_goal(first)
        return run_flights(env, controller, starts, round(seconds / env.base_env.dt), goal_schedule=schedule)
    finally:
        env.close()
