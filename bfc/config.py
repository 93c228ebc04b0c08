"""Structured-config schemas: Hydra checks every override against these, so a typo is an error.

The env's own parameter dataclasses are reused as schema, so each default lives in one place.
Values are validated where they are used (the env and transform constructors name the key);
`validate(cfg)` also checks the training-level values before anything starts.
"""

from dataclasses import dataclass, field
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import MISSING  # noqa: F401  (re-exported for schemas that need it)

from bfc.envs import AirframeParams, RewardParams, StartParams, TerminationParams

ABLATIONS = ("ppo", "jd", "css", "tdts", "jd_css", "jd_tdts", "css_tdts", "jd_css_tdts")


@dataclass
class EnvConfig:
    num_envs: int = 256
    control_hz: float = 100.0  # the paper flew 250 Hz; 100 Hz learns faster and as well (docs/training.md)
    physics_dt: float = 0.002
    episode_seconds: float = 5.0
    goal: list[float] = field(default_factory=lambda: [0.0, 0.0, 1.5])
    start_motors: str = "rest"
    num_threads: int | None = None  # MuJoCo rollout threads; None = all cores
    airframe: AirframeParams = field(default_factory=AirframeParams)
    reward: RewardParams = field(default_factory=RewardParams)
    termination: TerminationParams = field(default_factory=TerminationParams)
    start: StartParams = field(default_factory=StartParams)


@dataclass
class JDConfig:
    enabled: bool = True
    p0: float = 1.0
    decay_frames: int = 10_000_000  # = collector.total_frames: p falls to 0 as training ends
    schedule: str = "linear"  # linear | cosine | constant
    z_range: list[float] = field(default_factory=lambda: [0.5, 3.0])
    roll_range: list[float] = field(default_factory=lambda: [-60.0, 60.0])  # degrees
    pitch_range: list[float] = field(default_factory=lambda: [-60.0, 60.0])
    yaw_range: list[float] = field(default_factory=lambda: [-180.0, 180.0])
    velocity_range: list[float] = field(default_factory=lambda: [0.0, 0.0])  # m/s, per axis
    angular_velocity_range: list[float] = field(default_factory=lambda: [0.0, 0.0])  # deg/s, per axis


@dataclass
class CSSConfig:
    enabled: bool = True
    grid: int = 4  # squares per side of the (x, y) start area
    temperature: float = 1.0  # in units of the spread of the square values
    uniform: float = 0.2  # share of starts drawn uniformly over squares


@dataclass
class TDTSConfig:
    enabled: bool = True
    zeta: float = 0.1  # metres, per axis
    threshold_seconds: float = 1.0
    as_terminal: bool = False  # False: reported as truncated (bootstrapped); see bfc/transforms/tdts.py


@dataclass
class NoiseConfig:
    kind: str = "none"  # none | gaussian | ou
    std: Any = 0.05  # a number or 18 numbers
    theta: float = 1.0  # OU mean reversion (1/s)
    elements: Any = "all"  # all | position | [indices]


@dataclass
class ModelConfig:
    actor_hidden: list[int] = field(default_factory=lambda: [64, 64])  # the paper: [256, 256], 3x slower update
    critic_hidden: list[int] = field(default_factory=lambda: [128, 128])
    activation: str = "tanh"  # tanh | relu | elu
    init_std: float = 0.2
    include_acceleration: bool = False
    action_map: str = "thrust"  # thrust | speed: how the policy's [-1, 1] maps to motor speed (transforms/action.py)


@dataclass
class CollectorConfig:
    total_frames: int = 10_000_000  # rounded up to whole batches
    frames_per_batch: int = 16_384


@dataclass
class LossConfig:
    kind: str = "clip"  # clip (ClipPPOLoss, eq. 11) | kl (KLPENPPOLoss, adaptive beta, eq. 12)
    gamma: float = 0.99  # a 1 s horizon at 100 Hz; use 0.996 (and lmbda 0.98) at 250 Hz
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    dtarg: float = 0.01
    entropy_coeff: float = 0.0
    critic_coeff: float = 0.5
    epochs: int = 5
    minibatch_size: int = 4096


@dataclass
class OptimConfig:
    lr: float = 3e-4
    max_grad_norm: float = 1.0
    anneal_lr: bool = False


@dataclass
class LoggerConfig:
    tensorboard: bool = True
    log_interval: int = 1  # batches
    progress: bool = True


@dataclass
class EvalConfig:
    interval_frames: int = 1_000_000
    num_starts: int = 100
    seed: int = 0
    seconds: float = 10.0
    threshold: float = 0.10
    hold_seconds: float = 1.0


@dataclass
class CheckpointConfig:
    interval_frames: int = 2_000_000
    keep_best: bool = True  # policy.pt = the best evaluation so far (false: the latest)


@dataclass
class Config:
    seed: int = 0
    variant: str = "jd_css_tdts"  # the ablation variant's name, set by conf/ablation/*.yaml (logging, run dirs)
    resume: str | None = None  # a run directory to continue
    torch_threads: int = 2  # for the PPO update; collection and update never overlap
    env: EnvConfig = field(default_factory=EnvConfig)
    jd: JDConfig = field(default_factory=JDConfig)
    css: CSSConfig = field(default_factory=CSSConfig)
    tdts: TDTSConfig = field(default_factory=TDTSConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)


def register() -> None:
    ConfigStore.instance().store(name="base_config", node=Config)


def _check(cond: bool, key: str, allowed: str, value) -> None:
    if not cond:
        raise ValueError(f"{key} must be {allowed}, got {value!r}")


def validate(cfg) -> None:
    """Training-level checks; env and transform values are checked by their constructors."""
    c = cfg.collector
    _check(c.total_frames > 0, "collector.total_frames", "> 0", c.total_frames)
    _check(c.frames_per_batch > 0, "collector.frames_per_batch", "> 0", c.frames_per_batch)
    _check(
        c.frames_per_batch % cfg.env.num_envs == 0,
        "collector.frames_per_batch",
        f"a multiple of env.num_envs ({cfg.env.num_envs})",
        c.frames_per_batch,
    )
    lo = cfg.loss
    _check(lo.kind in ("clip", "kl"), "loss.kind", "'clip' or 'kl'", lo.kind)
    _check(0 < lo.gamma <= 1, "loss.gamma", "in (0, 1]", lo.gamma)
    _check(0 <= lo.lmbda <= 1, "loss.lmbda", "in [0, 1]", lo.lmbda)
    _check(lo.epochs >= 1, "loss.epochs", ">= 1", lo.epochs)
    _check(
        0 < lo.minibatch_size <= c.frames_per_batch,
        "loss.minibatch_size",
        f"in [1, collector.frames_per_batch={c.frames_per_batch}]",
        lo.minibatch_size,
    )
    _check(cfg.optim.lr > 0, "optim.lr", "> 0", cfg.optim.lr)
    _check(
        cfg.model.activation in ("tanh", "relu", "elu"), "model.activation", "tanh, relu or elu", cfg.model.activation
    )
    _check(cfg.model.init_std > 0, "model.init_std", "> 0", cfg.model.init_std)
    _check(cfg.noise.kind in ("none", "gaussian", "ou"), "noise.kind", "none, gaussian or ou", cfg.noise.kind)
    _check(cfg.eval.interval_frames > 0, "eval.interval_frames", "> 0", cfg.eval.interval_frames)
    _check(cfg.eval.num_starts >= 1, "eval.num_starts", ">= 1", cfg.eval.num_starts)
    _check(cfg.checkpoint.interval_frames > 0, "checkpoint.interval_frames", "> 0", cfg.checkpoint.interval_frames)
    _check(cfg.torch_threads >= 1, "torch_threads", ">= 1", cfg.torch_threads)
