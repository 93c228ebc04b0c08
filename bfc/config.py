"""Structured-config schemas: every key a run or an evaluation accepts, with its default.

Importing this module registers the schemas with Hydra's ConfigStore (`base_config` for
conf/config.yaml, `base_evaluate` for conf/evaluate.yaml), so `compose(overrides)` works from a
notebook as `python train.py ...` does from the shell. The composed config is closed: a key the
schema does not define is an error whether or not it came with `+` (`check_keys`).
The schema's defaults are what `python train.py` runs (the full BFC plus bfc's robust extras);
`extras=none` (conf/extras/none.yaml, which every paper variant uses) lists what the paper's
variants run instead. The env's own parameter dataclasses are reused as schema (their fields and
checks); where the default run differs from the env's own defaults (the reward's body-rate weight,
the randomisation), the schema says so. Values are validated where they are used (the env and
transform constructors name the key); `validate(cfg)` checks the training-level values and
`check_overrides` the command line before anything starts. A key that moved (`MOVED`) fails in
its old spelling with one line naming the new one.
"""

from __future__ import annotations

import dataclasses
import difflib
import functools
import math
import types
import typing
from dataclasses import dataclass, field, make_dataclass
from pathlib import Path
from typing import Any, Optional

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf

from bfc.checks import check
from bfc.envs.params import GOAL, AirframeParams, EnvParams, JDParams, RandomizeParams, RewardParams
from bfc.keys import ACTIVATION_NAMES, OBSERVATION_SCALE_NAMES

CONF_DIR = Path(__file__).resolve().parents[1] / "conf"  # the repository's Hydra configs

ABLATIONS = ("ppo", "jd", "css", "tdts", "jd_css", "jd_tdts", "css_tdts", "jd_css_tdts")
ALGORITHMS = ("ppo", "trpo", "ddpg")  # conf/algo/; bfc.training.learners.make_learner builds each
EVALUATION_SUITES = ("paper", "robust", "hardware")  # evaluate.py suite=...
SIMULATORS = ("mujoco", "rotorpy")  # evaluate.py sim=... (rotorpy: bfc/evaluation/rotorpy_sim.py)
# evaluate.py controller= and baselines=: bfc.controllers.CONTROLLERS' names, here so that a bad
# name fails before torch and OSQP load (tests/test_entry_points.py checks they agree)
CONTROLLER_NAMES = ("lee", "lee_i", "mpc")
ROTORPY_AIRFRAMES = ("bfc", "rotorpy")  # evaluate.py rotorpy_airframe=... (docs/evaluation.md)
COLLECTORS = ("fused", "torchrl")
OBJECTIVES = ("final_success_rate", "best_success_rate", "seconds_to_0.905")  # train.py's return value
CRITIC_LOSSES = ("l2", "l1", "smooth_l1")  # TorchRL's loss_critic_type
LOSS_IMPLEMENTATIONS = ("bfc", "torchrl")  # PPO's clipped step: bfc.training.ppo_step or TorchRL's module


@dataclass
class EnvConfig(EnvParams):
    """The env's parameters (bfc.envs.EnvParams) with the batch, the threads and the defaults the
    default run trains with where they differ from the env's own."""

    num_envs: int = 256
    num_threads: int | None = None  # MuJoCo rollout threads; None = all cores
    # MuJoCo's step while training (s); null: one step per control step. evaluate.py's test flights
    # always fly the reference simulator (0.002 s); docs/env.md, "Physics step". (The paper flew
    # 250 Hz; the control rate's 100 Hz learns faster and as well: docs/training.md.)
    physics_dt: float | None = None
    # a fifth of the env's body-rate penalty: fast flips recover from upside down (extras=none: 0.005);
    # a precision bonus 3 cm wide, not 10: the hover within a millimetre, and within 1 cm on a noisy
    # estimate (docs/training.md, "Latency in training"; extras=none and +preset=prompt: 0.1)
    reward: RewardParams = field(default_factory=lambda: RewardParams(angular_velocity=0.001, precision_radius=0.03))
    # a new airframe and wind every episode, as multipliers of the nominal airframe (extras=none: off)
    randomize: RandomizeParams = field(
        default_factory=lambda: RandomizeParams(
            external_force=1.0, mass=(0.7, 1.3), inertia=(1.0, 1.5), motor_constant=(0.8, 1.2), motor_lag=(1.0, 3.0)
        )
    )


@dataclass
class JDConfig(JDParams):
    """In-air starts at any attitude, thrown and spinning, many upside down; p(t) falls from p0 to
    p_end over decay_frames (extras=none: the paper's +-60 deg at rest, p falling to 0; the
    paper's values are bfc.envs.JDParams' defaults)."""

    enabled: bool = True
    p_end: float = 0.75  # p at decay_frames and after (the paper: 0)
    decay_frames: int | None = None  # None: collector.total_frames, so p reaches p_end as training ends
    roll_range: tuple[float, float] = (-180.0, 180.0)  # degrees (paper: +-60)
    pitch_range: tuple[float, float] = (-90.0, 90.0)  # (paper: +-60)
    # thrown and spun: with a late estimate a policy must learn to catch these (before: +-1, +-115)
    velocity_range: tuple[float, float] = (-3.0, 3.0)  # m/s, per axis (paper: 0)
    angular_velocity_range: tuple[float, float] = (-230.0, 230.0)  # deg/s, per axis
    inverted_share: float = 0.6  # of the right-way-up air starts, turned upside down (x curriculum progress)
    inverted_spread: float = 0.5  # their roll, pitch x this before the turn (with the curriculum): nearer 180 deg


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
class CurriculumConfig:
    """Widen JD's attitude and velocity ranges and env.randomize from `start` (a fraction of
    them) to all of them over the first `frames` frames (bfc/collectors/curriculum.py); 0: off
    (extras=none)."""

    frames: int = 2_000_000
    start: float = 0.33


@dataclass
class NoiseConfig:
    kind: str = "none"  # none | gaussian | ou
    std: Any = 0.05  # a number or 18 numbers
    theta: float = 1.0  # OU mean reversion (1/s)
    elements: Any = "all"  # all | position | [indices]
    # a constant offset per episode (a gyro's bias, an estimator's drift), N(0, bias^2) drawn at
    # each reset: a number or 18 numbers (applies to every element, whatever `elements` says)
    bias: Any = 0.0


@dataclass
class LatencyConfig:
    """What a flight computer adds (bfc/transforms/latency.py): odometry `observation_steps`
    control steps old, commands applied `action_steps` late; a number, or [low, high] for a delay
    drawn per env at each reset (uniform over the integers). 0: off (extras=none). Trained
    through both, the policy flies a flight computer's late estimate (docs/training.md)."""

    observation_steps: Any = field(default_factory=lambda: [0, 5])  # 0-50 ms at 100 Hz, drawn per episode
    action_steps: Any = 1  # commands 10 ms late
    # the delays grow from none to these over curriculum.frames (bfc/collectors/curriculum.py);
    # false: all of them from the first frame (with them from frame 0, seed 2 never learned to fly)
    curriculum: bool = True


# model.observation_scales: one optional key per constant (null: the policy default), so that
# `model.observation_scales.<name>=...` needs no "+" and a misspelt name is refused
ObservationScalesConfig = make_dataclass(
    "ObservationScalesConfig",
    [(name, Optional[float], None) for name in OBSERVATION_SCALE_NAMES],  # noqa: UP045
)
ObservationScalesConfig.__module__ = __name__  # pickled configs (launchers, workers) find it here


@dataclass
class ModelConfig:
    """The policy (bfc.agent.PolicySpec reads these) and the critic."""

    actor_hidden: list[int] = field(default_factory=lambda: [128, 128])  # extras=none: [64, 64]; paper: [256, 256]
    critic_hidden: list[int] = field(default_factory=lambda: [128, 128])
    activation: str = "relu"  # relu | tanh | elu; relu learns to fly in half the frames of tanh (docs/training.md)
    init_std: float = 0.2
    # a ceiling on the std (null: free). PPO under latency widens it; capping it did not help there,
    # optim.desired_kl did (docs/training.md, "Latency in training")
    max_std: float | None = None
    include_acceleration: bool = False
    # the integral of the position error as 3 more inputs: lets the policy remove a steady offset
    # (mass, thrust, wind) as a PID's integral term does (bfc/transforms/observation.py; extras=none: off)
    position_integral: bool = True
    # the k commands before the previous one as 4 k more inputs: what a policy needs to predict
    # through latency, from which it tells how late its odometry is (bfc/transforms/observation.py;
    # docs/training.md, "Latency in training"; extras=none: 0)
    command_history: int = 4
    observation: str = "heading"  # heading (22 numbers, bfc's) | odometry (18, the paper's; +preset=paper)
    squash: bool = False  # tanh on the actor's mean (algo=ddpg sets it: its actor climbs the critic's gradient)
    action_map: str = "thrust"  # thrust | speed: how the policy's [-1, 1] maps to motor speed (transforms/action.py)
    # running mean/std of the observation in front of actor and critic, saved in the policy file
    # (OpenAI Baselines' VecNormalize; +preset=paper). bfc's own observation is scaled by hand
    normalize_observation: bool = False
    # the observation's scales, clip and integral constants, any of keys.OBSERVATION_SCALE_NAMES
    # (e.g. model.observation_scales.integral_settled_radius=0.3: the integral within 0.3 m only,
    # as before the settled band); the rest are bfc.transforms.OBSERVATION_SCALES. The policy file
    # stores them all (docs/transforms.md, "Policy-side maps")
    observation_scales: ObservationScalesConfig = field(default_factory=lambda: ObservationScalesConfig())


@dataclass
class CollectorConfig:
    total_frames: int = 6_000_000  # rounded up to whole batches (8M bought nothing more: docs/training.md)
    frames_per_batch: int = 8_192  # 256 envs x 32 steps: twice the updates of 16k batches for the same frames
    # Stop early once `stop_patience` consecutive in-training evaluations reach this success rate
    # (e.g. 0.99): for a flying policy rather than a fixed budget. null: run total_frames.
    stop_at_success: float | None = None
    stop_patience: int = 3
    # fused: bfc's collector (the same batches as TorchRL's, bfc's transforms only); torchrl:
    # TorchRL's Collector over the TransformedEnv (any transform stack). docs/training.md, "Collectors"
    kind: str = "fused"
    # 0: collect in the learner's process, between updates; k >= 1: in k worker processes (each
    # num_envs / k envs) that collect the next batch while the learner updates (the policy one
    # update behind); docs/training.md, "Collectors"
    workers: int = 1


@dataclass
class LossConfig:
    """PPO's section (algo=ppo): TorchRL's ClipPPOLoss or KLPENPPOLoss, GAE, epochs and minibatches."""

    kind: str = "clip"  # clip (ClipPPOLoss, eq. 11) | kl (KLPENPPOLoss, adaptive beta, eq. 12)
    # bfc: the clipped loss's step with its gradients written out (ClipPPOLoss's to float rounding,
    # 0.7x its update time on one thread: bfc.training.ppo_step) | torchrl: ClipPPOLoss, autograd and torch's Adam (any
    # network; the KL-penalty loss always runs TorchRL's module)
    implementation: str = "bfc"
    gamma: float = 0.99  # a 1 s horizon at 100 Hz; use 0.996 (and lmbda 0.98) at 250 Hz
    lmbda: float = 0.95
    clip_epsilon: float = 0.2
    dtarg: float = 0.01
    # an entropy bonus (extras=none: 0): it keeps the std wide enough, late in a latency-trained run,
    # to learn the flip from near upside down (docs/training.md, "Latency in training")
    entropy_coeff: float = 0.004
    # the mirror loss (bfc/training/mirror.py): the mean square of the policy's mean in a mirrored
    # world against the mirror of its mean, over the airframe's reflections (0: off; PPO only)
    mirror_coeff: float = 0.0
    # all: each row mirrored through every reflection (an "x" has three: four times the actor's
    # rows) | one: through one, in turn by its place in the batch (the same loss in expectation,
    # half the actor's rows)
    mirror_reflections: str = "all"
    # the mirror loss from this frame on (0: from the first batch): the first flights are learned at
    # the update's full speed, the symmetry taught after
    mirror_from_frames: int = 0
    # degrees: the mirror loss only on rows tilted at most this from upright (180: every row). Upside
    # down a policy that is its own mirror image has no side to turn over to (docs/training.md)
    mirror_max_tilt: float = 180.0
    critic_coeff: float = 0.5
    critic_loss: str = "l2"  # l2 | l1 | smooth_l1: TorchRL's loss_critic_type
    # ClipPPOLoss's clip_value: the new value kept within this of the collected one (Baselines'
    # ppo2 clips it with the clip range; +preset=paper). null: off
    clip_value: float | None = None
    epochs: int = 2  # 2 passes of 16 minibatches (extras=none: 4)
    num_minibatches: int = 16  # per epoch; the minibatch is frames_per_batch / num_minibatches frames (512)
    minibatch_size: int | None = None  # set: a fixed size in frames instead (overrides num_minibatches)


@dataclass
class TRPOConfig:
    """algo=trpo: one natural-gradient step per batch within a KL bound, then the critic fitted."""

    max_kl: float = 0.01  # the KL bound of each step
    cg_iterations: int = 10  # conjugate-gradient iterations
    damping: float = 0.1  # Fisher damping
    line_search_steps: int = 10  # backtracking steps (halving the step each time)
    gamma: float = 0.99  # GAE
    lmbda: float = 0.95
    critic_epochs: int = 4  # Adam passes of the critic over each batch (lr: optim.lr)
    critic_minibatches: int = 16


@dataclass
class DDPGConfig:
    """algo=ddpg: replayed transitions, target networks, a deterministic actor."""

    buffer_size: int = 1_000_000  # transitions
    batch_size: int = 256  # the minibatch
    updates_per_batch: int = 64  # gradient steps per collected batch
    tau: float = 0.005  # Polyak tau of the target networks
    actor_lr: float = 1e-4
    critic_lr: float = 1e-3
    warmup_frames: int = 10_000  # transitions stored before the first update
    gamma: float = 0.99  # TD(0) target


@dataclass
class AlgoConfig:
    """The learning algorithm (config group `algo`: conf/algo/ppo.yaml, trpo.yaml, ddpg.yaml). Each
    reads its own section: PPO `loss`, TRPO `algo.trpo`, DDPG `algo.ddpg` (and all of them `optim`)."""

    name: str = "ppo"  # ppo (the paper's BFC) | trpo | ddpg (the paper's comparisons, figs. 5-7)
    trpo: TRPOConfig = field(default_factory=TRPOConfig)
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)


@dataclass
class OptimConfig:
    lr: float = 1e-3  # PPO, and TRPO's critic (DDPG: algo.ddpg.actor_lr / critic_lr)
    max_grad_norm: float = 1.0
    adam_eps: float = 1e-8  # Adam's epsilon (torch's default; Baselines' ppo2: 1e-5)
    # every learner: rewards divided by the running std of the discounted return, clipped to +-10
    # (Baselines' VecNormalize; +preset=paper; bfc.agent.normalization.RewardScale). Logged
    # rewards stay unscaled
    normalize_reward: bool = False
    anneal_lr: bool = (
        True  # linear decay to 0 at the last frame: the final policy is the settled one (extras=none: off)
    )
    # PPO: a target for each update's mean KL (null: off); the rate falls by 1.5x after an update
    # beyond twice it and climbs back (up to optim.lr) below half of it (rsl_rl's adaptive
    # schedule; bfc/training/lr_schedule.py). Latency training needs it (docs/training.md;
    # extras=none, algo=trpo, algo=ddpg: null)
    desired_kl: float | None = 0.05


@dataclass
class LoggerConfig:
    tensorboard: bool = True
    log_interval: int = 1  # batches
    progress: bool = True
    # at each evaluation, a short video of one validation flight (the start released most tilted)
    # under TensorBoard's `eval/video` (Images tab, an animated GIF); rendered by MuJoCo, so it needs
    # an OpenGL backend (docs/training.md, "Watching a run")
    video: bool = False


@dataclass
class ProtocolConfig:
    """The paper's protocol: how many starts, the flight length and the success rule (bfc.evaluation.judge)."""

    num_starts: int = 100
    seconds: float = 10.0
    threshold: float = 0.10  # metres, per axis
    hold_seconds: float = 1.0


@dataclass
class EvalConfig(ProtocolConfig):
    """In-training evaluation: the protocol on validation starts (policy.pt is chosen on these)."""

    validation_seed: int = 1  # protocol_starts seed: not the test starts (seed 0) that evaluate.py and the docs report
    interval_frames: int = 1_000_000  # after early_frames: a settled run needs few looks
    # denser evaluations early, when a run first flies (about 0.5M frames for the default): every
    # early_interval_frames until early_frames
    early_frames: int = 1_000_000  # 0: off
    early_interval_frames: int = 250_000
    at_start: bool = False  # also fly the untrained policy at frame 0 (a curve's first point; ~5 s)
    # MuJoCo's step for the validation flights; null: the training step (env.physics_dt). evaluate.py's
    # test flights always fly the reference 0.002 s (bfc.envs.REFERENCE_PHYSICS_DT)
    physics_dt: float | None = None
    # fly the validation flights in a process of their own while training goes on (the same
    # history and policy.pt; in place anyway with collector.stop_at_success or logger.video)
    background: bool = True


@dataclass
class CheckpointConfig:
    interval_frames: int = 2_000_000
    keep_best: bool = True  # policy.pt = the best evaluation so far (false: the latest)
    # End this process at this frame count with a checkpoint, policy files and a summary marked
    # paused (a sweep reports the job "paused"); the run itself is unchanged (its schedules still
    # end at collector.total_frames) and the same command resumes it, to a later pause_at_frames
    # or to the end. For a long sweep run in stages. null: off
    pause_at_frames: int | None = None


@dataclass
class Config:
    """`python train.py` with no override runs exactly these defaults (conf/config.yaml adds
    nothing to them); `extras=none` and every `+ablation=...` switch bfc's robust extras off."""

    seed: int = 0
    variant: str = "jd_css_tdts_robust"  # the variant's name, set by conf/ablation/*.yaml (logging, run dirs)
    resume: str | None = None  # a run directory to continue
    # what train.py returns (a sweeper optimises it): final_success_rate | best_success_rate |
    # seconds_to_0.905 (training wall-clock to the paper's success rate; NaN if never reached)
    sweep_objective: str = "final_success_rate"
    # torch threads for the update; null: the cores the collector workers leave (2 on 2 cores with
    # collector.workers=0, 1 with the default workers=1); 0: every core (for a run with a worker
    # whose update dwarfs its collection: the worker's share of a core is short)
    torch_threads: int | None = None
    env: EnvConfig = field(default_factory=EnvConfig)
    jd: JDConfig = field(default_factory=JDConfig)
    css: CSSConfig = field(default_factory=CSSConfig)
    tdts: TDTSConfig = field(default_factory=TDTSConfig)
    curriculum: CurriculumConfig = field(default_factory=CurriculumConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    latency: LatencyConfig = field(default_factory=LatencyConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    algo: AlgoConfig = field(default_factory=AlgoConfig)
    collector: CollectorConfig = field(default_factory=CollectorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    optim: OptimConfig = field(default_factory=OptimConfig)
    logger: LoggerConfig = field(default_factory=LoggerConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)
    checkpoint: CheckpointConfig = field(default_factory=CheckpointConfig)


@dataclass
class TestProtocolConfig(ProtocolConfig):
    seed: int = 0  # protocol_starts seed: 0 = the test starts that the docs report


@dataclass
class EvaluateConfig:
    """evaluate.py: one policy or controller on the protocol, or a whole suite (report.md)."""

    policy: str | None = None  # path to a policy.pt
    controller: str | None = None  # a classical controller name (bfc.evaluation.CONTROLLERS)
    # what a controller (and the baselines) fly: a built-in (conf/env/airframe/) or an airframe file; null:
    # the policy's own airframe (a policy flies only the one it was trained on), else the Hummingbird
    airframe: str | None = None
    # paper: protocol, accuracy, noise, waypoints, baselines (report.md); robust: robust.md;
    # hardware: hardware.md (latency, estimator noise and gyro bias, a throw)
    suite: str | None = None
    runs: str | None = None  # suite=paper: a directory of training runs for Table 2 and learning curves
    baselines: list[str] = field(default_factory=lambda: ["mpc", "lee"])  # suites: flown beside it
    figures: bool = True  # single evaluation: flight figures beside results.json
    goal: list[float] = field(default_factory=lambda: list(GOAL))  # single evaluation
    eval: TestProtocolConfig = field(default_factory=TestProtocolConfig)
    noise: NoiseConfig = field(default_factory=NoiseConfig)  # single evaluation: seen by the controller only
    sim: str = "mujoco"  # the simulator flown: mujoco (bfc's env) | rotorpy (docs/evaluation.md)
    rotorpy_airframe: str = "bfc"  # sim=rotorpy: the policy's bfc airframe | rotorpy (RotorPy's own of it)
    # Videos rendered by MuJoCo (bfc.evaluation.video; docs/evaluation.md, "Videos"): video.mp4 and
    # video.gif beside results.json (suite=robust: video_<row>.mp4/.gif per row)
    video: bool = False
    video_starts: int = 4  # flights filmed, one after another (suite=robust: per row)
    video_pick: str = "tilted"  # tilted: the starts released most tilted | first: the first starts
    video_camera: str = "chase"  # chase: follows the drone | fixed: looks at the goal from 7 m
    video_seconds: float | None = 5.0  # of each flight from its release (null: the whole flight)
    video_fps: float = 20.0  # the MP4's (the GIF keeps at most 15 frames per second)
    video_width: int = 480
    video_height: int = 360


# Keys that moved: the old spelling fails with one line naming the new one.
MOVED = {
    "config": {
        "eval.seed": "eval.validation_seed",
        **{f"algo.{k}": f"algo.trpo.{k}" for k in ("max_kl", "cg_iterations", "damping", "line_search_steps")},
        **{
            f"algo.{k}": f"algo.ddpg.{k}"
            for k in ("buffer_size", "batch_size", "updates_per_batch", "tau", "actor_lr", "critic_lr", "warmup_frames")
        },
    },
    "evaluate": {k: f"eval.{k}" for k in ("num_starts", "seed", "seconds", "threshold", "hold_seconds")},
}


def register() -> None:
    """Put the schemas in Hydra's ConfigStore (done on import; calling it again is harmless)."""
    cs = ConfigStore.instance()
    cs.store(name="base_config", node=Config)
    cs.store(name="base_evaluate", node=EvaluateConfig)


register()

SCHEMAS = {"config": Config, "evaluate": EvaluateConfig}
GROUPS = {"config": ("ablation", "preset"), "evaluate": ()}


def compose(overrides=(), config_name: str = "config") -> DictConfig:
    """The config `python train.py <overrides>` (or evaluate.py, config_name="evaluate") would run
    with, from anywhere: a notebook, a test, a script. Unknown keys and bad values raise ValueError."""
    from hydra import compose as hydra_compose
    from hydra import initialize_config_dir
    from hydra.errors import HydraException
    from omegaconf.errors import OmegaConfBaseException

    if config_name not in SCHEMAS:
        raise ValueError(f"config_name must be one of {sorted(SCHEMAS)}, got {config_name!r}")
    if config_name == "config":
        overrides = expand_airframe(overrides)
    try:
        with initialize_config_dir(config_dir=str(CONF_DIR), version_base="1.3"):
            cfg = hydra_compose(config_name=config_name, overrides=list(overrides))
    except (HydraException, OmegaConfBaseException) as err:
        raise ValueError(str(err).splitlines()[0]) from None
    check_keys(cfg, config_name)
    return cfg


def _schema_keys(schema) -> list[str]:
    """The keys of a schema node: a dataclass instance's fields (walking dataclass instances
    rather than `OmegaConf.structured` costs microseconds instead of a fifth of a second)."""
    return [f.name for f in dataclasses.fields(schema)] if dataclasses.is_dataclass(schema) else []


def _unknown(node, schema, prefix: str = ""):
    keys = _schema_keys(schema)
    for key in node:
        full = f"{prefix}{key}"
        if key not in keys:
            return full, prefix.rstrip(".") or "the top level", keys
        child, sub = node[key], getattr(schema, key)
        if isinstance(child, dict) and dataclasses.is_dataclass(sub):
            found = _unknown(child, sub, f"{full}.")
            if found:
                return found
    return None


def check_keys(cfg, config_name: str = "config") -> None:
    """Raise ValueError on the first key of `cfg` that the schema does not define (a typo, a
    `+key=value` that names nothing, or a key that moved: the message names its new spelling)."""
    plain = OmegaConf.to_container(cfg, resolve=False) if OmegaConf.is_config(cfg) else dict(cfg)
    plain.pop("hydra", None)
    found = _unknown(plain, SCHEMAS[config_name]())
    if found:
        raise ValueError(_unknown_message(*found, config_name))


def _unknown_message(key: str, where: str, allowed, config_name: str) -> str:
    moved = MOVED[config_name].get(key)
    if moved:
        return f"{key} has moved: it is {moved} now"
    groups = GROUPS[config_name]
    hint = f"; config groups: {', '.join(f'+{g}=...' for g in groups)}" if groups and "." not in key else ""
    close = difflib.get_close_matches(key.rsplit(".", 1)[-1], list(allowed), n=1)
    guess = f" (did you mean {key.rsplit('.', 1)[0] + '.' if '.' in key else ''}{close[0]}?)" if close else ""
    return f"unknown config key {key!r}{guess}; {where} has: {', '.join(allowed)}{hint}"


def config_groups() -> dict[str, list[str]]:
    """{group: [option, ...]} of the repository's Hydra config groups (conf/<group>/<option>.yaml,
    nested ones as env/airframe)."""
    dirs = sorted({f.parent for f in CONF_DIR.rglob("*.yaml")} - {CONF_DIR})
    return {d.relative_to(CONF_DIR).as_posix(): sorted(f.stem for f in d.glob("*.yaml")) for d in dirs}


WIND_LIMIT = 0.5  # the strongest training wind, as a share of the airframe's weight

# A user's airframe file (`env.airframe=path/to/file.yaml`): these fields it must give, the others
# take neutral values (no rotor or IMU masses, no rotor drag), never the Hummingbird's.
AIRFRAME_FILE_REQUIRED = (
    "body_mass",
    "inertia",
    "layout",
    "arm_length",
    "motor_constant",
    "moment_constant",
    "max_rotor_speed",
    "time_constant_up",
    "time_constant_down",
    "hull_half_size",
)
AIRFRAME_FILE_DEFAULTS = {
    "rotor_mass": 0.0,
    "imu_mass": 0.0,
    "rotor_height": 0.0,
    "rotor_drag_coefficient": 0.0,
    "rolling_moment_coefficient": 0.0,
}


AIRFRAME_GROUP = "env/airframe"  # the config group of the built-in airframes (conf/env/airframe/)


def builtin_airframes() -> list[str]:
    """The built-in airframes: conf/env/airframe/<name>.yaml."""
    return sorted(f.stem for f in (CONF_DIR / AIRFRAME_GROUP).glob("*.yaml"))


def airframe_params(name: str) -> AirframeParams:
    """A built-in airframe by name, or a user's airframe file by path, as AirframeParams."""
    if name in builtin_airframes():
        node = OmegaConf.to_container(OmegaConf.load(CONF_DIR / AIRFRAME_GROUP / f"{name}.yaml"))
        return AirframeParams(**(node or {}).get("env", {}).get("airframe", {}))
    return AirframeParams(**load_airframe_file(name))


def load_airframe_file(path) -> dict:
    """Every AirframeParams field of a user's airframe file (YAML, the fields at its top level),
    checked: a missing, unknown or bad field is one ValueError line naming it and the file."""
    from omegaconf.errors import OmegaConfBaseException

    path = Path(path)
    if not path.is_file():
        raise ValueError(
            f"env.airframe={path}: no such file; a built-in ({', '.join(builtin_airframes())}) or a YAML file of "
            "airframe fields (docs/airframes.md)"
        )
    try:
        node = OmegaConf.load(path)
    except (OmegaConfBaseException, OSError, ValueError) as err:
        raise ValueError(f"{path}: not a YAML file of airframe fields ({str(err).splitlines()[0]})") from None
    given = OmegaConf.to_container(node) if OmegaConf.is_dict(node) else None
    if not isinstance(given, dict):
        raise ValueError(f"{path}: must hold airframe fields (body_mass: 0.03, ...), got {type(given).__name__}")
    known = _schema_keys(AirframeParams())
    unknown = [k for k in given if k not in known]
    if unknown:
        raise ValueError(f"{path}: unknown airframe field {unknown[0]!r}; fields: {', '.join(known)}")
    missing = [k for k in AIRFRAME_FILE_REQUIRED if k not in given]
    if missing:
        raise ValueError(f"{path}: missing airframe field(s) {', '.join(missing)} (docs/airframes.md lists each)")
    out = {"name": path.stem, **AIRFRAME_FILE_DEFAULTS, **given}
    try:
        out = dataclasses.asdict(AirframeParams(**out))
    except ValueError as err:
        raise ValueError(f"{path}: {err}") from None
    return {k: (list(v) if isinstance(v, tuple) else v) for k, v in out.items()}


def _override_value(v) -> str:
    if isinstance(v, (list, tuple)):
        return "[" + ",".join(_override_value(x) for x in v) + "]"
    return f"'{v}'" if isinstance(v, str) else repr(v)


def expand_airframe(overrides) -> list[str]:
    """`env.airframe=<built-in>` is the config group `env/airframe=<built-in>` (a sweep too:
    `env.airframe=hummingbird,crazyflie`); `env.airframe=<file.yaml>` sets every field from the
    file, before the command line's own `env.airframe.*` (which still override one value).
    Anything else passes unchanged."""
    out, files = [], []
    for o in overrides:
        key, sep, value = o.partition("=")
        if not sep or key.lstrip("+~") != "env.airframe":
            out.append(o)
            continue
        options = value.split(",")
        if all(v in builtin_airframes() for v in options):
            out.append(f"{AIRFRAME_GROUP}={value}")
        elif len(options) == 1 and value.endswith((".yaml", ".yml")):
            files.append(value)
        else:
            bad = next(v for v in options if v not in builtin_airframes())
            raise ValueError(
                f"env.airframe={bad} is not an airframe: a built-in ({', '.join(builtin_airframes())}) or a path to a "
                "YAML file (one per run, not in a sweep), e.g. env.airframe=my_drone.yaml"
            )
    if len(files) > 1:
        raise ValueError(f"env.airframe is given twice ({', '.join(files)}): one airframe per run")
    if files:
        if any(o.partition("=")[0] == AIRFRAME_GROUP for o in out):
            raise ValueError(f"env.airframe=<file> and {AIRFRAME_GROUP}=<built-in> both name the airframe: keep one")
        fields = load_airframe_file(files[0])
        out = [f"env.airframe.{k}={_override_value(v)}" for k, v in fields.items()] + out
    return out


def check_overrides(overrides, config_name: str = "config") -> None:
    """Check command-line overrides before Hydra sees them, so that a key that names nothing, a
    moved key, an unknown group option or a syntax error is one line (ValueError) rather than
    Hydra's multi-line report: every key must be in the schema, every group option in conf/.
    Sweep values (`seed=0,1`) are checked option by option; `hydra.*` and `hydra/...` are Hydra's."""
    from hydra.core.override_parser.overrides_parser import OverridesParser
    from hydra.errors import OverrideParseException

    try:
        parsed = OverridesParser.create().parse_overrides(list(overrides))
    except OverrideParseException as err:
        raise ValueError(f"cannot parse the overrides: {str(err).splitlines()[0]}") from None
    groups = config_groups() if config_name == "config" else {}
    schema = SCHEMAS[config_name]()
    _check_preset_algo(parsed)
    for o in parsed:
        key = o.key_or_group
        if key == "hydra" or key.startswith(("hydra.", "hydra/")):
            continue
        if key in groups:
            options = list(o.sweep_string_iterator()) if o.is_sweep_override() else [o.get_value_element_as_str()]
            bad = [v for v in options if v not in groups[key]]
            if bad and not o.is_delete():
                raise ValueError(f"{key}={bad[0]} is not a config of conf/{key}/; available: {', '.join(groups[key])}")
            continue
        node, parts, parent = schema, key.split("."), None
        for i, part in enumerate(parts):
            if part not in _schema_keys(node):
                where = ".".join(parts[:i]) or "the top level"
                raise ValueError(_unknown_message(key, where, _schema_keys(node), config_name))
            parent, node = node, getattr(node, part)
        if not o.is_delete() and parent is not None:
            for value in _values(o):
                _check_value(key, _field_types(type(parent)).get(parts[-1], Any), value)


def _values(override) -> list:
    """The values an override gives (each option of a sweep; none for a range or interval sweep,
    which Hydra and the sweeper check)."""
    if not override.is_sweep_override():
        return [override.value()]
    try:
        return list(override.sweep_iterator())
    except Exception:  # noqa: BLE001 - an interval sweep: its bounds are the sweeper's
        return []


@functools.cache
def _field_types(cls) -> dict:
    try:
        return typing.get_type_hints(cls)
    except Exception:  # noqa: BLE001 - an annotation that does not resolve: its values are OmegaConf's to check
        return {}


_TYPE_NAMES = {bool: "true or false", int: "an integer", float: "a number", str: "a string"}


def _parses(kind, v) -> bool:
    try:
        kind(v)
    except ValueError:
        return False
    return True


# What OmegaConf converts to each type on merging (a quoted '3' is an integer, 1 is true)
_FITS = {
    bool: lambda v: (
        isinstance(v, (bool, int))
        or (isinstance(v, str) and v.lower() in ("true", "false", "yes", "no", "on", "off", "y", "n"))
    ),
    int: lambda v: (isinstance(v, int) and not isinstance(v, bool)) or (isinstance(v, str) and _parses(int, v)),
    float: lambda v: (
        (isinstance(v, (int, float)) and not isinstance(v, bool)) or (isinstance(v, str) and _parses(float, v))
    ),
    str: lambda v: not isinstance(v, (list, dict)),
}


def _check_value(key: str, tp, value) -> None:
    """A value of the wrong type for its field, or a plain value for a whole section: one line
    naming the key and what it takes (Hydra's own report is 5-12 lines)."""
    if isinstance(value, str) and "${" in value:
        return  # an interpolation: resolved later
    origin, args = typing.get_origin(tp), typing.get_args(tp)
    if origin in (typing.Union, types.UnionType):
        if value is None and type(None) in args:
            return
        rest = [a for a in args if a is not type(None)]
        tp, origin = (rest[0], typing.get_origin(rest[0])) if len(rest) == 1 else (Any, None)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            fields = ", ".join(f"{key}.{f}" for f in _schema_keys(tp)[:4])
            raise ValueError(f"{key} is a config section, not a value (got {value!r}): set its keys ({fields}, ...)")
        return
    sequence = origin in (list, tuple) or tp in (list, tuple)
    if tp not in _FITS and not sequence:
        return  # Any, a union of several types: OmegaConf's to check
    what = "a list ([a, b, ...])" if sequence else _TYPE_NAMES[tp]
    if value is None:
        raise ValueError(f"{key} cannot be null; it takes {what}")
    if not (isinstance(value, list) if sequence else _FITS[tp](value)):
        raise ValueError(f"{key} takes {what}, got {value!r}")


# Each paper preset trains one algorithm (conf/preset/paper*.yaml): the paper's widths and
# Baselines' defaults differ per algorithm, so `algo=` beside one names the preset to use instead.
PAPER_PRESETS = {"paper": "ppo", "paper_trpo": "trpo", "paper_ddpg": "ddpg"}


def _check_preset_algo(parsed) -> None:
    chosen = {o.key_or_group: o.get_value_element_as_str() for o in parsed if not o.is_sweep_override()}
    preset, algo = chosen.get("preset"), chosen.get("algo")
    if preset in PAPER_PRESETS and algo is not None and algo != PAPER_PRESETS[preset]:
        name = {v: k for k, v in PAPER_PRESETS.items()}.get(algo)
        raise ValueError(
            f"+preset={preset} trains {PAPER_PRESETS[preset]}; for algo={algo} use +preset={name} instead (no algo=)"
        )


def minibatch_size(cfg) -> int:
    """Frames per PPO minibatch: loss.minibatch_size if set, else frames_per_batch / num_minibatches."""
    lo = cfg.loss
    if lo.minibatch_size is not None:
        return int(lo.minibatch_size)
    return max(1, int(cfg.collector.frames_per_batch) // int(lo.num_minibatches))


def jd_decay_frames(cfg) -> int:
    """Frames over which JD's probability falls to jd.p_end: jd.decay_frames if set, else the run's length."""
    d = cfg.jd.decay_frames
    return int(cfg.collector.total_frames if d is None else d)


def check_frames_per_batch(frames_per_batch: int, num_envs: int) -> None:
    """A batch is whole steps of every env: `validate` and FusedCollector (built from a config or
    not) both check it here."""
    check(
        frames_per_batch % num_envs == 0,
        "collector.frames_per_batch",
        f"a multiple of env.num_envs ({num_envs})",
        frames_per_batch,
    )


def validate(cfg) -> None:
    """Training-level checks; env and transform values are checked by their constructors."""
    check_keys(cfg)
    # a bad airframe value: one line, before anything starts
    airframe = AirframeParams(**OmegaConf.to_container(cfg.env.airframe))
    wind = cfg.env.randomize.external_force
    check(
        wind <= WIND_LIMIT * airframe.weight,
        "env.randomize.external_force",
        f"at most {WIND_LIMIT:.0%} of the airframe's weight ({airframe.weight:.3g} N; the built-ins train with 14%: "
        f"{0.14 * airframe.weight:.2g} N)",
        wind,
    )
    mass, k_f = cfg.env.randomize.mass, cfg.env.randomize.motor_constant
    own, floor = airframe.thrust_to_weight, cfg.env.randomize.min_thrust_to_weight
    check(
        floor < own,
        "env.randomize.min_thrust_to_weight",
        f"below the airframe's own thrust-to-weight {own:.2f} (0: off)",
        floor,
    )
    lift = own * k_f[0] * airframe.mass_gain(mass[1])
    check(
        max(lift, floor) > 1.0,
        "env.randomize.mass",
        f"ranges whose heaviest body with the weakest motors can still lift itself (here thrust-to-weight "
        f"{lift:.2f} at mass x{mass[1]:g}, motor constant x{k_f[0]:g}; the airframe's own is {own:.2f}; "
        "or a floor env.randomize.min_thrust_to_weight above 1)",
        list(mass),
    )
    check(cfg.sweep_objective in OBJECTIVES, "sweep_objective", ", ".join(OBJECTIVES), cfg.sweep_objective)
    c = cfg.collector
    num_envs = cfg.env.num_envs
    check(isinstance(num_envs, int) and num_envs >= 1, "env.num_envs", "an integer >= 1", num_envs)
    check(c.total_frames > 0, "collector.total_frames", "> 0", c.total_frames)
    check(c.frames_per_batch > 0, "collector.frames_per_batch", "> 0", c.frames_per_batch)
    if c.stop_at_success is not None:
        check(0 <= c.stop_at_success <= 1, "collector.stop_at_success", "null or in [0, 1]", c.stop_at_success)
    check(c.stop_patience >= 1, "collector.stop_patience", ">= 1", c.stop_patience)
    check_frames_per_batch(c.frames_per_batch, cfg.env.num_envs)
    check(c.kind in COLLECTORS, "collector.kind", " or ".join(COLLECTORS), c.kind)
    check(
        isinstance(c.workers, int) and c.workers >= 0 and (c.workers == 0 or num_envs % c.workers == 0),
        "collector.workers",
        f"0 (in the learner's process) or a number of worker processes that divides env.num_envs ({num_envs})",
        c.workers,
    )
    lo = cfg.loss
    check(lo.kind in ("clip", "kl"), "loss.kind", "'clip' or 'kl'", lo.kind)
    check(lo.implementation in LOSS_IMPLEMENTATIONS, "loss.implementation", "'bfc' or 'torchrl'", lo.implementation)
    check(lo.critic_loss in CRITIC_LOSSES, "loss.critic_loss", ", ".join(CRITIC_LOSSES), lo.critic_loss)
    check(
        isinstance(lo.mirror_coeff, (int, float)) and 0 <= lo.mirror_coeff < math.inf,
        "loss.mirror_coeff",
        "a number >= 0 (0: off)",
        lo.mirror_coeff,
    )
    check(lo.mirror_reflections in ("all", "one"), "loss.mirror_reflections", "'all' or 'one'", lo.mirror_reflections)
    check(
        isinstance(lo.mirror_from_frames, int) and lo.mirror_from_frames >= 0,
        "loss.mirror_from_frames",
        "an integer >= 0 (the frames after which the mirror loss runs)",
        lo.mirror_from_frames,
    )
    check(
        isinstance(lo.mirror_max_tilt, (int, float)) and 0 < lo.mirror_max_tilt <= 180,
        "loss.mirror_max_tilt",
        "degrees in (0, 180] (180: every row)",
        lo.mirror_max_tilt,
    )
    check(
        lo.mirror_coeff == 0 or cfg.algo.name == "ppo",
        "loss.mirror_coeff",
        f"0 with algo={cfg.algo.name} (the mirror loss is PPO's)",
        lo.mirror_coeff,
    )
    _check_updates("loss", lo.gamma, lo.lmbda, ("epochs", lo.epochs), ("num_minibatches", lo.num_minibatches), c)
    if lo.minibatch_size is not None:
        check(
            0 < lo.minibatch_size <= c.frames_per_batch,
            "loss.minibatch_size",
            f"null or in [1, collector.frames_per_batch={c.frames_per_batch}]",
            lo.minibatch_size,
        )
    pause = cfg.checkpoint.pause_at_frames
    if pause is not None:
        check(pause > 0, "checkpoint.pause_at_frames", "null (off) or > 0", pause)
    check(cfg.curriculum.frames >= 0, "curriculum.frames", ">= 0 (0: off)", cfg.curriculum.frames)
    check(0 <= cfg.curriculum.start <= 1, "curriculum.start", "in [0, 1]", cfg.curriculum.start)
    if cfg.jd.decay_frames is not None:
        d = cfg.jd.decay_frames
        check(d >= 0, "jd.decay_frames", "null (= collector.total_frames) or >= 0", d)
    check(cfg.optim.lr > 0, "optim.lr", "> 0", cfg.optim.lr)
    check(cfg.optim.adam_eps > 0, "optim.adam_eps", "> 0", cfg.optim.adam_eps)
    kl = cfg.optim.desired_kl
    check(kl is None or (isinstance(kl, (int, float)) and 0 < kl < math.inf), "optim.desired_kl", "null or > 0", kl)
    check(
        kl is None or cfg.algo.name == "ppo",
        "optim.desired_kl",
        f"null with algo={cfg.algo.name} (it adapts PPO's step)",
        kl,
    )
    if lo.clip_value is not None:
        check(lo.clip_value > 0, "loss.clip_value", "null (off) or > 0", lo.clip_value)
    a = cfg.algo
    check(a.name in ALGORITHMS, "algo.name", f"one of {', '.join(ALGORITHMS)} (conf/algo/)", a.name)
    t = a.trpo
    check(t.max_kl > 0, "algo.trpo.max_kl", "> 0", t.max_kl)
    check(t.cg_iterations >= 1, "algo.trpo.cg_iterations", ">= 1", t.cg_iterations)
    check(t.line_search_steps >= 1, "algo.trpo.line_search_steps", ">= 1", t.line_search_steps)
    check(t.damping >= 0, "algo.trpo.damping", ">= 0", t.damping)
    epochs, minibatches = ("critic_epochs", t.critic_epochs), ("critic_minibatches", t.critic_minibatches)
    _check_updates("algo.trpo", t.gamma, t.lmbda, epochs, minibatches, c)
    d = a.ddpg
    check(
        d.batch_size >= 1 and d.buffer_size >= d.batch_size,
        "algo.ddpg.batch_size",
        f"in [1, algo.ddpg.buffer_size={d.buffer_size}]",
        d.batch_size,
    )
    check(d.updates_per_batch >= 1, "algo.ddpg.updates_per_batch", ">= 1", d.updates_per_batch)
    check(0 < d.tau <= 1, "algo.ddpg.tau", "in (0, 1]", d.tau)
    check(d.actor_lr > 0, "algo.ddpg.actor_lr", "> 0", d.actor_lr)
    check(d.critic_lr > 0, "algo.ddpg.critic_lr", "> 0", d.critic_lr)
    check(d.warmup_frames >= 0, "algo.ddpg.warmup_frames", ">= 0", d.warmup_frames)
    check(0 < d.gamma <= 1, "algo.ddpg.gamma", "in (0, 1]", d.gamma)
    names = ACTIVATION_NAMES
    allowed = f"{', '.join(names[:-1])} or {names[-1]}"
    check(cfg.model.activation in names, "model.activation", allowed, cfg.model.activation)
    for name in OBSERVATION_SCALE_NAMES:
        value = getattr(cfg.model.observation_scales, name)
        ok = value is None or (isinstance(value, (int, float)) and math.isfinite(value) and value > 0)
        check(ok, f"model.observation_scales.{name}", "> 0 or null", value)
    check(cfg.model.init_std > 0, "model.init_std", "> 0", cfg.model.init_std)
    max_std = cfg.model.max_std
    check(
        max_std is None or (isinstance(max_std, (int, float)) and cfg.model.init_std <= max_std < math.inf),
        "model.max_std",
        f"null or a number >= model.init_std ({cfg.model.init_std})",
        max_std,
    )
    check(cfg.noise.kind in ("none", "gaussian", "ou"), "noise.kind", "none, gaussian or ou", cfg.noise.kind)
    bias = cfg.noise.bias
    values = list(bias) if isinstance(bias, (list, tuple)) or OmegaConf.is_list(bias) else [bias]
    check(
        len(values) in (1, 18) and all(isinstance(v, (int, float)) and 0 <= v < math.inf for v in values),
        "noise.bias",
        "a number >= 0 or 18 of them",
        bias,
    )
    if cfg.noise.kind == "none":
        check(
            max(values) == 0,
            "noise.bias",
            "0 with noise.kind=none (a bias alone: noise.kind=gaussian noise.std=0)",
            bias,
        )
    check(cfg.eval.interval_frames > 0, "eval.interval_frames", "> 0", cfg.eval.interval_frames)
    check(cfg.eval.early_frames >= 0, "eval.early_frames", ">= 0 (0: off)", cfg.eval.early_frames)
    check(cfg.eval.early_interval_frames > 0, "eval.early_interval_frames", "> 0", cfg.eval.early_interval_frames)
    if cfg.eval.physics_dt is not None:
        check(cfg.eval.physics_dt > 0, "eval.physics_dt", "null (the training step) or > 0", cfg.eval.physics_dt)
    if cfg.env.physics_dt is not None:
        check(cfg.env.physics_dt > 0, "env.physics_dt", "null (one step per control step) or > 0", cfg.env.physics_dt)
    check_protocol(cfg.eval)
    check(cfg.checkpoint.interval_frames > 0, "checkpoint.interval_frames", "> 0", cfg.checkpoint.interval_frames)
    if cfg.torch_threads is not None:
        allowed = "null (the cores the workers leave), 0 (every core) or >= 1"
        check(cfg.torch_threads >= 0, "torch_threads", allowed, cfg.torch_threads)
    if cfg.logger.video:
        check(cfg.logger.tensorboard, "logger.video", "false when logger.tensorboard=false (it logs there)", True)


def _check_updates(section: str, gamma, lmbda, epochs: tuple, minibatches: tuple, collector) -> None:
    """GAE's gamma and lambda, the passes over a batch and the minibatches of one (PPO's `loss`,
    TRPO's `algo.trpo`)."""
    fpb = collector.frames_per_batch
    check(0 < gamma <= 1, f"{section}.gamma", "in (0, 1]", gamma)
    check(0 <= lmbda <= 1, f"{section}.lmbda", "in [0, 1]", lmbda)
    check(epochs[1] >= 1, f"{section}.{epochs[0]}", ">= 1", epochs[1])
    check(
        1 <= minibatches[1] <= fpb,
        f"{section}.{minibatches[0]}",
        f"in [1, collector.frames_per_batch={fpb}]",
        minibatches[1],
    )


def check_protocol(p, section: str = "eval") -> None:
    """The protocol keys of `eval` (training) or evaluate.py's `eval` section."""
    check(p.num_starts >= 1, f"{section}.num_starts", ">= 1", p.num_starts)
    check(p.seconds > 0, f"{section}.seconds", "> 0", p.seconds)
    check(p.threshold > 0, f"{section}.threshold", "> 0 (metres)", p.threshold)
    check(0 < p.hold_seconds <= p.seconds, f"{section}.hold_seconds", f"in (0, {section}.seconds]", p.hold_seconds)
