"""make_env(cfg): the base env plus the transform stack the config asks for (`bfc.make_env`), and
make_flight_env: the env a flight from given starts runs in (evaluation, training's validation).

Train, evaluate, notebooks and tests all build envs here. Order matters and is fixed:
    TDTS (before CSS, whose episode bookkeeping must see TDTS's done) -> JD -> CSS -> given starts
    -> odometry noise -> latency (odometry, then commands) -> policy observation -> motor-speed action
    -> episode statistics (training).
This stack is the one written order of a control step: TorchRL's `env.step` walks it through the
transforms' hooks, and bfc.transforms.pipeline reads it into the list of stages the collector,
the flights and RotorPy run.
The policy's observation and action maps come from a PolicySpec (bfc.agent): the config's in
training, a policy file's in a flight.
"""

from __future__ import annotations

import zlib
from dataclasses import dataclass
from typing import Any

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict, TensorDictBase
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from bfc import keys
from bfc.agent import PolicySpec
from bfc.checks import check, finite
from bfc.config import jd_decay_frames
from bfc.envs import REFERENCE_PHYSICS_DT, AirframeParams, EnvParams, JDParams, QuadrotorEnv
from bfc.envs.params import as_params, params_from
from bfc.transforms import (
    ActionDelay,
    ControlledStartingState,
    GaussianOdometryNoise,
    GivenStarts,
    JumpingDistribution,
    ObservationDelay,
    OUOdometryNoise,
    TimeDependentTerminalState,
)
from bfc.transforms._base import BatchedTransform


def _plain(node):
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def env_params(cfg, airframe: dict | None = None, randomize: bool = True) -> EnvParams:
    """The config's `env` section as the env's EnvParams; `airframe` overrides AirframeParams
    fields of the simulated body only; randomize=False leaves `env.randomize` (training-time
    domain randomisation) off."""
    e = _plain(cfg.env)
    flown = {**(e.get("airframe") or {}), **dict(airframe or {})}
    return params_from(EnvParams, e, airframe=flown, randomize=e.get("randomize") if randomize else None)


def make_base_env(
    cfg, num_envs: int | None = None, airframe: dict | None = None, randomize: bool = True
) -> QuadrotorEnv:
    """The base env of `cfg` (`env_params`), `num_envs` of them (None: env.num_envs)."""
    e = cfg.env
    return QuadrotorEnv(int(num_envs or e.num_envs), env_params(cfg, airframe, randomize), num_threads=e.num_threads)


def physics_step(cfg) -> float:
    """MuJoCo's step for `cfg`: env.physics_dt, or one step per control step when it is null."""
    return env_params(cfg).physics_step


def make_noise(noise, num_envs: int, dt: float):
    """The odometry-noise transform for a `noise` config section (None for kind 'none')."""
    noise = _plain(noise) or {"kind": "none"}
    kind = noise.get("kind", "none")
    if kind == "none":
        return None
    std, elements, bias = noise.get("std", 0.05), noise.get("elements", "all"), noise.get("bias", 0.0)
    if kind == "gaussian":
        return GaussianOdometryNoise(num_envs, std=std, elements=elements, bias=bias)
    if kind == "ou":
        theta = float(noise.get("theta", 1.0))
        return OUOdometryNoise(num_envs, std=std, theta=theta, dt=dt, elements=elements, bias=bias)
    raise ValueError(f"noise.kind must be one of none, gaussian, ou, got {kind!r}")


def make_env(
    cfg,
    *,
    num_envs: int | None = None,
    samplers: bool = True,
    noise=None,
    given_starts: bool = False,
    policy_io: bool = True,
    seed: int | None = None,
    airframe: dict | None = None,
    latency=None,
) -> BFCEnv:
    """Build the env for `cfg`.

    samplers=False switches JD, CSS, TDTS, `env.randomize` and the episode statistics
    (RewardSum, StepCounter) off whatever the config says (the flown world is the nominal one
    unless `airframe` says otherwise);
    noise overrides `cfg.noise`; given_starts adds a GivenStarts transform (`env.transform`
    member) through which a caller places envs at chosen starts on the next reset;
    policy_io=False leaves out the policy's observation and action maps, for controllers that
    read `"odometry"` and `"goal"` and command motor speeds in rad/s themselves;
    airframe overrides AirframeParams fields of the flown body only (model mismatch): the policy's
    observation and action maps keep the nominal airframe of `cfg.env.airframe`;
    latency overrides `cfg.latency` ({"observation_steps": k, "action_steps": k}, each a number or
    [low, high]).
    """
    base = make_base_env(cfg, num_envs, airframe, randomize=samplers)
    n, dt = base.num_envs, base.dt
    ts = []
    if samplers and cfg.tdts.enabled:
        t = cfg.tdts
        ts.append(TimeDependentTerminalState(n, t.zeta, t.threshold_seconds, dt=dt, as_terminal=t.as_terminal))
    if samplers and cfg.jd.enabled:
        ts.append(JumpingDistribution(n, params_from(JDParams, _plain(cfg.jd), decay_frames=jd_decay_frames(cfg))))
    if samplers and cfg.css.enabled:
        c = cfg.css
        ts.append(
            ControlledStartingState(
                n, grid=int(c.grid), xy_range=base.start_params.xy_range, temperature=c.temperature, uniform=c.uniform
            )
        )
    policy = PolicySpec.from_config(cfg) if policy_io else None
    noise = cfg.noise if noise is None else noise
    latency = _plain(cfg.latency) if latency is None else latency
    delays = _delays(latency, base.num_envs, AirframeParams(**(_plain(cfg.env.airframe) or {})).hover_speed)
    return _assemble(
        base, ts, policy=policy, noise=noise, given_starts=given_starts, statistics=samplers, seed=seed, delays=delays
    )


def _delays(latency, num_envs: int, hover_speed: float) -> list:
    """The latency transforms for a `latency` section: odometry first, then commands."""
    latency = _plain(latency) or {}
    unknown = sorted(set(latency) - {"observation_steps", "action_steps", "curriculum"})
    check(not unknown, "latency", "observation_steps, action_steps and curriculum", unknown)
    out = []
    if latency.get("observation_steps", 0) not in (0, [0, 0]):
        out.append(ObservationDelay(num_envs, latency["observation_steps"]))
    if latency.get("action_steps", 0) not in (0, [0, 0]):
        out.append(ActionDelay(num_envs, latency["action_steps"], initial=hover_speed))
    return out


def trained_rate(trained_hz: float, control_hz=None, what="this policy") -> float:
    """The rate a policy flies at: the one it was trained at, whatever asks for another (a policy
    file, its ONNX export; `fly`, `fly_rotorpy`, `make_flight_env`). `control_hz` None: that rate."""
    if control_hz is not None and float(control_hz) != trained_hz:
        raise ValueError(f"{what} was trained at {trained_hz:g} Hz and is flown at that rate only")
    return trained_hz


FLIGHT_MARGIN = 1.0  # s: a flight's env runs its episodes this much longer, so no flight truncates


@dataclass
class FlightConditions:
    """What a flight from given starts flies through, beside its controller and its goal: its
    length, the rate and MuJoCo's step, the flown body (its mismatch from the nominal one the
    controller knows), the wind, and what reaches the controller (noise, latency).

    seconds: the flight's length; control_hz: the rate of a controller without one of its own (a
    policy file is always flown at its trained rate); physics_dt: MuJoCo's step, the reference by
    default; airframe: AirframeParams fields of the flown body that differ from the nominal one
    (model mismatch); nominal: the nominal airframe's fields for a controller without one (the
    Hummingbird when None; a policy flies its own); external_force: a constant force in newtons,
    world frame, (3,) or one per start (n, 3); noise: a `noise` config section, corrupting only
    what the controller sees; seed: the flight's random streams (noise, latency draws);
    observation_delay / action_delay: seconds of latency (bfc.transforms.latency), in whole
    control steps rounded down; start_motors: "rest" or "hover" at release.
    """

    seconds: float = 10.0
    control_hz: float | None = None
    physics_dt: float = REFERENCE_PHYSICS_DT
    airframe: dict | None = None
    nominal: dict | None = None
    external_force: Any = None
    noise: Any = None
    seed: int = 0
    observation_delay: float = 0.0
    action_delay: float = 0.0
    start_motors: str = "rest"

    def __post_init__(self) -> None:
        check(finite(self.seconds) and self.seconds > 0, "seconds", "> 0", self.seconds)
        for name in ("observation_delay", "action_delay"):
            v = getattr(self, name)
            check(finite(v) and v >= 0, name, ">= 0 seconds", v)


def make_flight_env(
    num_envs: int,
    flight: FlightConditions | dict | None = None,
    *,
    policy: PolicySpec | None = None,
    num_threads: int | None = None,
    **changes,
) -> BFCEnv:
    """An env for flights from given starts (`GivenStarts`) in `flight`'s conditions (a
    FlightConditions, or a mapping of its fields; `changes`: any of its fields by keyword): no
    samplers, no randomisation, no episode statistics, the task's termination.

    policy: a PolicySpec, whose observation and action maps the env gets and whose control rate
    and nominal airframe it flies (a policy file is always flown as it was trained); None: no
    policy maps, at `control_hz` (controllers read `"odometry"` and command rad/s).
    """
    f = as_params(FlightConditions, flight, **changes)
    rate = trained_rate(policy.control_hz, f.control_hz) if policy is not None else f.control_hz
    check(rate is not None, "control_hz", "given for a flight without a policy", rate)
    nominal = policy.airframe if policy is not None else dict(f.nominal or {})
    params = EnvParams(
        control_hz=float(rate),
        physics_dt=float(f.physics_dt),
        episode_seconds=float(f.seconds) + FLIGHT_MARGIN,
        airframe={**nominal, **dict(f.airframe or {})},
        start_motors=f.start_motors,
    )
    base = QuadrotorEnv(int(num_envs), params, num_threads=num_threads)
    steps = {
        "observation_steps": int(f.observation_delay / base.dt + 1e-6),
        "action_steps": int(f.action_delay / base.dt + 1e-6),
    }
    delays = _delays(steps, base.num_envs, AirframeParams(**nominal).hover_speed)
    env = _assemble(
        base, [], policy=policy, noise=f.noise, given_starts=True, statistics=False, seed=f.seed, delays=delays
    )
    if f.external_force is not None:
        base.set_external_force(f.external_force)
    return env


def _assemble(base: QuadrotorEnv, ts: list, *, policy, noise, given_starts, statistics, seed, delays=()) -> BFCEnv:
    """base env + the start samplers `ts` + given starts + noise + latency + the policy's maps +
    statistics (the command's delay acts on rad/s: TorchRL runs inverse transforms last to first)."""
    n, dt = base.num_envs, base.dt
    if given_starts:
        ts.append(GivenStarts(n))
    noise_t = make_noise(noise, n, dt)
    if noise_t is not None:
        ts.append(noise_t)
    ts.extend(delays)
    if policy is not None:
        ts.append(policy.make_observation_map(n, dt))
        ts.append(policy.make_action_map())
    if statistics:  # episode statistics for training's logs; flights judge whole trajectories instead
        ts.append(RewardSum())
        ts.append(StepCounter())
    env = BFCEnv(base, Compose(*ts))
    if seed is not None:
        env.set_seed(seed)
    return env


def transform_seed(seed: int, transform) -> int:
    """The seed of one transform's generator: the run's seed and the transform's class name, not
    its place in the stack, so switching TDTS on or off leaves the JD and CSS random streams alone."""
    return (int(seed) + zlib.crc32(type(transform).__name__.encode())) % 2**63


class BFCEnv(TransformedEnv):
    """A TransformedEnv whose `set_seed` also seeds bfc's transforms (noise, samplers), each from
    its own seed (`transform_seed`); TorchRL's TransformedEnv seeds only the base env.

    `state_dict()` / `load_state_dict()` (nn.Module's) hold the whole state: the base env's
    physics, motors, counters, goals and generator, and every transform's buffers and generator.
    """

    def state_dict(self, *args, **kwargs):
        sd = super().state_dict(*args, **kwargs)  # TorchRL's: the transforms only
        for key, value in self.base_env.state_dict().items():
            sd[f"base_env.{key}"] = value
        return sd

    def load_state_dict(self, state_dict, strict: bool = True, **kwargs):
        base = {k.removeprefix("base_env."): v for k, v in state_dict.items() if k.startswith("base_env.")}
        rest = {k: v for k, v in state_dict.items() if not k.startswith("base_env.")}
        if strict and not base:
            raise ValueError("this state dict has no base_env entries: not a BFCEnv state dict")
        self.base_env.load_state_dict(base, strict=strict)
        self.transform.load_state_dict(rest, strict=strict, **kwargs)

    direct_reset = True  # False: TorchRL's generic maybe_reset (the reference the direct one is tested against)

    def reset_envs(self, done: torch.Tensor, start_state: torch.Tensor | None = None) -> TensorDictBase:
        """Reset the envs in `done` (N,) or (N, 1) bool, at `start_state` (N, 12) where it is not
        NaN: the samplers' `_reset_env_preprocess` last to first, the base env's `_reset`, every
        transform's `_reset`, in TorchRL's order. The reset outputs of every env (valid for `done`)."""
        request = TensorDict({keys.RESET: done.reshape(self.batch_size + (1,)).clone()}, batch_size=self.batch_size)
        if start_state is not None:
            request.set(keys.START_STATE, start_state)
        request = self.transform._reset_env_preprocess(request)
        return self.transform._reset(request, self.base_env._reset(request))

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        # TorchRL's TransformedEnv._reset keeps only the reset and state keys of its input, so a
        # "start_state" given to reset() would be dropped silently: it is an input here.
        start = None if tensordict is None else tensordict.get(keys.START_STATE, None)
        if start is None:
            return super()._reset(tensordict, **kwargs)
        done = tensordict.get(keys.RESET, None)
        done = torch.ones(self.batch_size + (1,), dtype=torch.bool) if done is None else done
        return self.reset_envs(done, start)

    def maybe_reset(self, tensordict: TensorDictBase) -> TensorDictBase:
        """TorchRL's partial reset of the envs that are done, without its generic plumbing.

        Nearly every collection step resets a few of the envs, and TorchRL's path (mark
        `"_reset"`, select, check, merge) costs more than the transforms' own work. This one runs
        the same calls in the same order (`reset_envs`, then the masked merge TorchRL does), so
        the result is the same bit for bit (tests/training/test_hot_path.py).
        """
        done = tensordict.get(keys.DONE, None)
        if not self.direct_reset or done is None:
            return super().maybe_reset(tensordict)
        if not bool(done.any()):
            return tensordict
        fresh = self.reset_envs(done)
        if bool(done.all()):  # TorchRL updates rather than merges: entries only in `tensordict` stay
            return tensordict.update(fresh, update_batch_size=True)
        keep = ~done.reshape(self.batch_size)
        return tensordict.where(keep, other=fresh, out=tensordict, pad=0, update_batch_size=True)

    def set_seed(self, seed: int | None = None, static_seed: bool = False):
        out = super().set_seed(seed, static_seed=static_seed)
        if seed is not None:
            for t in self.transform:
                if isinstance(t, BatchedTransform):
                    t.set_seed(transform_seed(seed, t))
        return out


def find_transform(env: TransformedEnv, cls):
    """The first transform of type `cls` in the env's stack, or None."""
    for t in env.transform:
        if isinstance(t, cls):
            return t
    return None
