"""make_env(cfg): the base env plus the transform stack the config asks for.

Train, evaluate, notebooks and tests all build envs here. Order matters and is fixed:
    TDTS (before CSS, whose episode bookkeeping must see TDTS's done) -> JD -> CSS -> given starts
    -> odometry noise -> policy observation -> motor-speed action -> episode statistics.
"""

from __future__ import annotations

from omegaconf import OmegaConf
from torchrl.envs import Compose, RewardSum, StepCounter, TransformedEnv

from bfc.envs import QuadrotorEnv
from bfc.transforms import (
    ControlledStartingState,
    GaussianOdometryNoise,
    GivenStarts,
    JumpingDistribution,
    MotorSpeedAction,
    OUOdometryNoise,
    PolicyObservation,
    TimeDependentTerminalState,
)
from bfc.transforms._base import BatchedTransform


def _plain(node):
    return OmegaConf.to_container(node, resolve=True) if OmegaConf.is_config(node) else node


def make_base_env(cfg, num_envs: int | None = None) -> QuadrotorEnv:
    e = cfg.env
    return QuadrotorEnv(
        int(num_envs or e.num_envs),
        control_hz=e.control_hz,
        physics_dt=e.physics_dt,
        episode_seconds=e.episode_seconds,
        goal=tuple(e.goal),
        airframe=_plain(e.airframe),
        reward=_plain(e.reward),
        termination=_plain(e.termination),
        start=_plain(e.start),
        start_motors=e.start_motors,
        num_threads=e.num_threads,
    )


def make_noise(noise, num_envs: int, dt: float):
    """The odometry-noise transform for a `noise` config section (None for kind 'none')."""
    noise = _plain(noise) or {"kind": "none"}
    kind = noise.get("kind", "none")
    if kind == "none":
        return None
    std, elements = noise.get("std", 0.05), noise.get("elements", "all")
    if kind == "gaussian":
        return GaussianOdometryNoise(num_envs, std=std, elements=elements)
    if kind == "ou":
        return OUOdometryNoise(num_envs, std=std, theta=float(noise.get("theta", 1.0)), dt=dt, elements=elements)
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
) -> TransformedEnv:
    """Build the env for `cfg`.

    samplers=False switches JD, CSS and TDTS off whatever the config says (evaluation);
    noise overrides `cfg.noise`; given_starts adds a GivenStarts transform (`env.transform`
    member) through which a caller places envs at chosen starts on the next reset;
    policy_io=False leaves out the policy's observation and action maps, for controllers that
    read `"odometry"` and `"goal"` and command motor speeds in rad/s themselves.
    """
    base = make_base_env(cfg, num_envs)
    n, dt = base.num_envs, base.dt
    ts = []
    if samplers and cfg.tdts.enabled:
        t = cfg.tdts
        ts.append(TimeDependentTerminalState(n, t.zeta, t.threshold_seconds, dt=dt, as_terminal=t.as_terminal))
    if samplers and cfg.jd.enabled:
        j = cfg.jd
        ts.append(
            JumpingDistribution(
                n,
                p0=j.p0,
                decay_frames=int(j.decay_frames),
                schedule=j.schedule,
                z_range=tuple(j.z_range),
                roll_range=tuple(j.roll_range),
                pitch_range=tuple(j.pitch_range),
                yaw_range=tuple(j.yaw_range),
                velocity_range=tuple(j.velocity_range),
                angular_velocity_range=tuple(j.angular_velocity_range),
            )
        )
    if samplers and cfg.css.enabled:
        c = cfg.css
        ts.append(
            ControlledStartingState(
                n, grid=int(c.grid), xy_range=base.start_params.xy_range, temperature=c.temperature, uniform=c.uniform
            )
        )
    if given_starts:
        ts.append(GivenStarts(n))
    noise_t = make_noise(cfg.noise if noise is None else noise, n, dt)
    if noise_t is not None:
        ts.append(noise_t)
    if policy_io:
        action = MotorSpeedAction(base.hover_speed, base.max_rotor_speed, cfg.model.action_map)
        ts.append(
            PolicyObservation(
                n,
                base.hover_speed,
                include_acceleration=cfg.model.include_acceleration,
                command_to_action=action.to_action,
            )
        )
        ts.append(action)
    ts.append(RewardSum())
    ts.append(StepCounter())
    env = BFCEnv(base, Compose(*ts))
    if seed is not None:
        env.set_seed(seed)
    return env


class BFCEnv(TransformedEnv):
    """A TransformedEnv whose `set_seed` also seeds bfc's transforms (noise, samplers), each from
    its own offset of the seed; TorchRL's TransformedEnv seeds only the base env."""

    def set_seed(self, seed: int | None = None, static_seed: bool = False):
        out = super().set_seed(seed, static_seed=static_seed)
        if seed is not None:
            for i, t in enumerate(self.transform):
                if isinstance(t, BatchedTransform):
                    t.set_seed(seed + 7919 * (i + 1))
        return out


def find_transform(env: TransformedEnv, cls):
    """The first transform of type `cls` in the env's stack, or None."""
    for t in env.transform:
        if isinstance(t, cls):
            return t
    return None
