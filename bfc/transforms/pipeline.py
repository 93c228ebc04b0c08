"""One control step, written once: the physics and bfc's transforms as one ordered list of stages.

`make_env`'s stack is the order. `Pipeline.of(env)` reads it into stages: the transforms that act
on the command (the action map, then the command's delay: TorchRL runs its inverse transforms
last to first), the physics, then every other transform in the stack's order. A stage has two
methods over one `StepState` of plain tensors: `advance(state)`, one control step, and
`restart(state, mask)`, the envs in `mask` starting an episode. The training collector
(bfc.collectors.fused), the flights (bfc.evaluation.flights) and RotorPy's runner iterate the same
list; each transform's TorchRL hooks call the same two methods on a state made of their
TensorDicts' entries, so TorchRL's `env.step` and the pipeline are one computation (tested bit for
bit over stacks in tests/collectors/test_pipeline.py).
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch

from bfc.envs.quadrotor import FLAT_GOAL, FLAT_ODOMETRY, FLAT_POSITION, FLAT_REWARD, QuadrotorEnv


@dataclass
class StepState:
    """What the stages hand on, (n, ...) each; None where no stage has written it yet."""

    action: torch.Tensor | None = None  # the policy's action in [-1, 1] (the action map's input)
    command: torch.Tensor | None = None  # motor speeds as commanded (rad/s)
    applied: torch.Tensor | None = None  # motor speeds the physics applies (the command, or a late one)
    truth: torch.Tensor | None = None  # the physics' outputs (n, 30), QuadrotorEnv's FLAT_* layout
    position: torch.Tensor | None = None  # true position (n, 3)
    goal: torch.Tensor | None = None  # (n, 3)
    reward: torch.Tensor | None = None  # (n,)
    terminated: torch.Tensor | None = None  # (n,) bool
    truncated: torch.Tensor | None = None  # (n,) bool
    odometry: torch.Tensor | None = None  # what the controller sees (n, 18): noisy, late
    observation: torch.Tensor | None = None  # the policy's input
    start: torch.Tensor | None = None  # (n, 12) requested starts, NaN: drawn (restart only)

    def set_truth(self, flat: torch.Tensor) -> None:
        """The physics' outputs, and the entries that are views into them."""
        self.truth, self.odometry = flat, flat[:, FLAT_ODOMETRY]
        self.position, self.goal, self.reward = flat[:, FLAT_POSITION], flat[:, FLAT_GOAL], flat[:, FLAT_REWARD.start]

    def merge(self, mask: torch.Tensor, fresh: StepState) -> None:
        """The carried entries of the envs in `mask` from `fresh` (a restart's), the rest kept."""
        m = mask.unsqueeze(-1)
        seen = {name: getattr(fresh, name) for name in ("odometry", "observation")}
        seen = {name: torch.where(m, new, getattr(self, name)) for name, new in seen.items() if new is not None}
        self.set_truth(torch.where(m, fresh.truth, self.truth))  # and its views
        for name, value in seen.items():
            setattr(self, name, value)


class Stage:
    """One step of the pipeline. Defaults do nothing: a stage writes only what it owns."""

    before_physics = False  # acts on the command (TorchRL: an inverse transform)

    def advance(self, state: StepState) -> None:
        """One control step."""

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        """The envs in `mask` (n,) start an episode."""


class Physics(Stage):
    """A simulator as a stage: `advance` applies `state.applied` (or `state.command`) and writes
    `state.truth` (QuadrotorEnv's FLAT_* layout, `set_truth`) and the done flags; `restart` places
    the envs at `state.start` (NaN: drawn). MuJoCo here, RotorPy in bfc.evaluation.rotorpy_sim."""

    def set_goal(self, state: StepState, goal) -> None:
        """Every env's goal from now on (a flight's waypoint), also in `state.goal`."""
        raise NotImplementedError


class MuJoCoPhysics(Physics):
    """QuadrotorEnv as a stage; a restart places the envs at the starts the samplers draw (each
    fills what is still NaN, TorchRL's pre-reset order: the stack last to first)."""

    def __init__(self, env: QuadrotorEnv, samplers=()):
        self.env, self.samplers = env, list(samplers)

    def advance(self, state: StepState) -> None:
        flat, state.terminated, state.truncated = self.env.advance(
            state.command if state.applied is None else state.applied
        )
        state.set_truth(flat)

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        start = state.start
        for sampler in self.samplers:
            start = sampler.draw_starts(mask, start)
        state.set_truth(self.env.restart(mask, start))

    def set_goal(self, state: StepState, goal) -> None:
        self.env.set_goal(goal)
        state.goal = self.env.goal


class UnknownStage(ValueError):
    """The stack holds a transform that is not a pipeline stage (TorchRL's own or a user's)."""


class Pipeline:
    """The stages of one env in the order one control step runs them."""

    def __init__(self, transforms, physics: Physics, num_envs: int):
        """transforms: stages in the stack's order; physics: the simulator's stage."""
        ts = list(transforms)
        unknown = [type(t).__name__ for t in ts if not isinstance(t, Stage)]
        if unknown:
            raise UnknownStage(", ".join(unknown))
        before = [t for t in reversed(ts) if t.before_physics]
        self.stages = [*before, physics, *(t for t in ts if not t.before_physics)]
        self.physics, self.num_envs = physics, int(num_envs)

    @classmethod
    def of(cls, env, ignore: tuple = ()) -> Pipeline:
        """The pipeline of a `make_env` env: its transforms in the stack's order around MuJoCo;
        transforms of the types in `ignore` are left to the caller (the collector's episode
        statistics). Raises UnknownStage naming any other that is not a stage."""
        ts = [t for t in env.transform if not isinstance(t, ignore)]
        samplers = [t for t in reversed(ts) if hasattr(t, "draw_starts")]
        return cls(ts, MuJoCoPhysics(env.base_env, samplers), env.base_env.num_envs)

    def step(self, state: StepState) -> StepState:
        """One control step: `state.action` (a policy's) or `state.command` (rad/s) in; the
        physics' outputs, done flags, odometry and observation out (new tensors)."""
        state.applied = None
        for stage in self.stages:
            stage.advance(state)
        return state

    def restart(self, state: StepState, mask: torch.Tensor) -> StepState:
        """New episodes for the envs in `mask`: every stage's restart on a fresh state (with
        `state.start`'s requests), whose carried entries then replace those of the envs in mask."""
        fresh = StepState(start=state.start)
        for stage in self.stages:
            stage.restart(fresh, mask)
        if state.truth is None:  # the first start: every entry is the fresh one
            for f in fields(StepState):
                setattr(state, f.name, getattr(fresh, f.name))
        else:
            state.merge(mask, fresh)
        state.start = None
        return state

    def start(self, start: torch.Tensor | None = None) -> StepState:
        """Every env's first episode (`start` (n, 12), NaN where drawn): a new carried state."""
        return self.restart(StepState(start=start), torch.ones(self.num_envs, dtype=torch.bool))
