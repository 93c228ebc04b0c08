"""PolicySpec: what a policy is, in one place.

Everything that must agree between training, a policy file, a flight and an export: the
observation (kind, accelerations, the position-error integral), the action map, the network
(sizes, activation, initial std, squash), the control rate and the nominal airframe the maps are
built on. The env's policy maps (`make_env`), the policy file (`save_policy` / `load_policy`), the
flight runner (`fly`) and the ONNX export all read it; nothing else carries these facts.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields

from bfc.agent.actor import ACTIVATIONS, GaussianActor
from bfc.checks import check
from bfc.envs import AirframeParams
from bfc.transforms import (
    ACTION_MAPS,
    OBSERVATION_SCALES,
    OBSERVATIONS,
    MotorSpeedAction,
    PolicyObservation,
    observation_size,
)
from bfc.transforms.observation import check_history


@dataclass
class PolicySpec:
    observation: str = "heading"  # heading (bfc's 22 numbers) | odometry (the paper's 18)
    include_acceleration: bool = False
    position_integral: bool = False  # the position-error integral as 3 more inputs
    command_history: int = 0  # the k commands before the previous one as 4 k more inputs
    action_map: str = "thrust"  # thrust | speed (bfc/transforms/action.py)
    hidden: tuple[int, ...] = (128, 128)  # the actor's hidden layers
    activation: str = "relu"
    init_std: float = 0.2
    max_std: float | None = None  # the std's ceiling in training (None: free)
    squash: bool = False  # tanh on the mean (DDPG)
    # running observation statistics in front of the MLP (the paper preset; bfc.agent.normalization)
    normalize_observation: bool = False
    control_hz: float = 100.0  # the rate the policy was trained at, and is flown at
    airframe: dict = field(default_factory=dict)  # the nominal airframe: AirframeParams overrides
    # the observation's scales, clip and integral constants (all of OBSERVATION_SCALES's names;
    # given ones override the defaults): part of the policy, so its file and exports carry them
    observation_scales: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        check(self.observation in OBSERVATIONS, "model.observation", " or ".join(OBSERVATIONS), self.observation)
        check(self.action_map in ACTION_MAPS, "model.action_map", " or ".join(ACTION_MAPS), self.action_map)
        check(self.activation in ACTIVATIONS, "model.activation", ", ".join(ACTIVATIONS), self.activation)
        self.hidden = tuple(self.hidden)
        check(
            len(self.hidden) >= 1 and all(isinstance(h, int) and h >= 1 for h in self.hidden),
            "model.actor_hidden",
            "a non-empty list of layer widths >= 1",
            list(self.hidden),
        )
        check(math.isfinite(self.init_std) and self.init_std > 0, "model.init_std", "> 0", self.init_std)
        if self.max_std is not None:
            self.max_std = float(self.max_std)
            check(
                math.isfinite(self.max_std) and self.max_std >= self.init_std,
                "model.max_std",
                f"null or a number >= model.init_std ({self.init_std})",
                self.max_std,
            )
        check(math.isfinite(self.control_hz) and self.control_hz > 0, "env.control_hz", "> 0", self.control_hz)
        self.include_acceleration, self.position_integral = (
            bool(self.include_acceleration),
            bool(self.position_integral),
        )
        check_history(self.command_history)
        check(
            self.command_history == 0 or self.observation == "heading",
            "model.command_history",
            "0 with model.observation=odometry (the paper's observation has no previous command)",
            self.command_history,
        )
        self.squash, self.control_hz, self.init_std = bool(self.squash), float(self.control_hz), float(self.init_std)
        self.normalize_observation = bool(self.normalize_observation)
        self.airframe = dict(self.airframe or {})
        self.nominal_airframe  # noqa: B018 - validates the overrides
        given = dict(self.observation_scales or {})
        unknown = sorted(set(given) - set(OBSERVATION_SCALES))
        check(not unknown, "observation_scales", f"among {', '.join(OBSERVATION_SCALES)}", unknown)
        self.observation_scales = {k: float(given.get(k, v)) for k, v in OBSERVATION_SCALES.items()}
        for k, v in self.observation_scales.items():
            check(math.isfinite(v) and v > 0, f"observation_scales.{k}", "> 0", v)

    @classmethod
    def from_config(cls, cfg) -> PolicySpec:
        """The spec a training config trains (`model.*`, `env.control_hz`, `env.airframe`)."""
        m, e = cfg.model, cfg.env
        airframe = {k: (v if isinstance(v, (int, float, str)) else list(v)) for k, v in dict(e.airframe).items()}
        return cls(
            observation=m.observation,
            include_acceleration=m.include_acceleration,
            position_integral=m.position_integral,
            command_history=m.command_history,
            action_map=m.action_map,
            hidden=tuple(int(h) for h in m.actor_hidden),
            activation=m.activation,
            init_std=m.init_std,
            max_std=m.max_std,
            squash=m.squash,
            normalize_observation=m.normalize_observation,
            control_hz=e.control_hz,
            airframe=airframe,
            observation_scales={
                k: float(getattr(m.observation_scales, k))
                for k in OBSERVATION_SCALES
                if getattr(m.observation_scales, k, None) is not None
            },
        )

    def to_dict(self) -> dict:
        """Plain data (numbers, strings, lists) for a policy file."""
        d = asdict(self)
        d["hidden"] = list(self.hidden)
        return d

    @classmethod
    def from_dict(cls, d: dict) -> PolicySpec:
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - known)
        if unknown:
            raise ValueError(f"policy spec has unknown fields {unknown}; known: {', '.join(sorted(known))}")
        return cls(**d)

    @property
    def nominal_airframe(self) -> AirframeParams:
        return AirframeParams(**self.airframe)

    @property
    def observation_size(self) -> int:
        return observation_size(
            self.observation, self.include_acceleration, self.position_integral, self.command_history
        )

    def make_net(self) -> GaussianActor:
        """A new (untrained) network of this shape."""
        return GaussianActor(
            self.observation_size,
            self.hidden,
            self.activation,
            self.init_std,
            self.squash,
            self.normalize_observation,
            self.max_std,
        )

    def make_action_map(self) -> MotorSpeedAction:
        a = self.nominal_airframe
        return MotorSpeedAction(a.hover_speed, a.max_rotor_speed, self.action_map)

    def make_observation_map(self, num_envs: int, dt: float | None = None) -> PolicyObservation:
        """The observation transform for `num_envs` envs stepping every `dt` s (1 / control_hz)."""
        action = self.make_action_map()
        return PolicyObservation(
            num_envs,
            self.nominal_airframe.hover_speed,
            include_acceleration=self.include_acceleration,
            command_to_action=action.to_action,
            position_integral=self.position_integral,
            dt=1.0 / self.control_hz if dt is None else dt,
            kind=self.observation,
            command_history=self.command_history,
            scales=self.observation_scales,
        )
