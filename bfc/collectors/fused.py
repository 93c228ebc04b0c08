"""bfc's own collector: the batches TorchRL's Collector gives, in one batched pass per step.

TorchRL's `Collector` over the env `make_env` builds spends most of a step in per-step machinery
(a TensorDict per call, the transforms walked one by one through their hooks, the partial reset's
select and merge). `FusedCollector` steps the same objects through their public tensor methods:
the actor's `sample`, the action map's `to_command`, `QuadrotorEnv.advance`, then each transform's
`advance` in the stack's order, and for the envs that are done the samplers' `draw_starts`,
`QuadrotorEnv.restart` and each transform's `restart`. It writes every step straight into the
batch's preallocated tensors and builds one TensorDict per batch, with the same keys, shapes and
values as TorchRL's Collector gives on the same env and seed (tests/collectors/test_fused.py, bit
for bit). It runs bfc's own transforms only: a stack with any other transform needs
`collector.kind=torchrl`.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.envs import RewardSum, StepCounter

from bfc import keys
from bfc.agent import GaussianActor
from bfc.config import check_frames_per_batch
from bfc.envs.quadrotor import FLAT_GOAL, FLAT_MOTORS, FLAT_ODOMETRY, FLAT_QUATERNION, FLAT_REWARD
from bfc.transforms import (
    ActionDelay,
    ControlledStartingState,
    GivenStarts,
    JumpingDistribution,
    MotorSpeedAction,
    ObservationDelay,
    OdometryNoise,
    PolicyObservation,
    TimeDependentTerminalState,
)
from bfc.transforms._base import StartSampler

_KNOWN = (
    TimeDependentTerminalState,
    JumpingDistribution,
    ControlledStartingState,
    GivenStarts,
    OdometryNoise,
    ObservationDelay,
    ActionDelay,
    PolicyObservation,
    MotorSpeedAction,
    RewardSum,
    StepCounter,
)


def _state(flat: torch.Tensor) -> dict:
    """The env's `"state"` entries as views into its outputs (QuadrotorEnv.pack's layout)."""
    return {
        "position": flat[..., 0:3],
        "quaternion": flat[..., FLAT_QUATERNION],
        "linear_velocity": flat[..., 3:6],
        "angular_velocity": flat[..., 12:15],
        "motor_speeds": flat[..., FLAT_MOTORS],
    }


class FusedCollector:
    """Batches of shape (num_envs, frames_per_batch / num_envs) from `env` (a `make_env` env)
    with the policy network `net` (shared: no weight copy is needed after an update)."""

    def __init__(self, env, net: GaussianActor, frames_per_batch: int, total_frames: int):
        unknown = [type(t).__name__ for t in env.transform if not isinstance(t, _KNOWN)]
        if unknown:
            raise ValueError(
                f"collector.kind=fused runs bfc's own transforms only; {', '.join(unknown)} "
                "needs collector.kind=torchrl"
            )
        self.env, self.net, self.base = env, net, env.base_env
        self.n = self.base.num_envs
        check_frames_per_batch(frames_per_batch, self.n)
        self.steps, self.total_frames, self.frames = frames_per_batch // self.n, int(total_frames), 0
        ts = list(env.transform)

        def one(cls):
            return next((t for t in ts if isinstance(t, cls)), None)

        self.tdts, self.jd, self.css = (
            one(TimeDependentTerminalState),
            one(JumpingDistribution),
            one(ControlledStartingState),
        )
        self.noise, self.observation, self.action_map = (
            one(OdometryNoise),
            one(PolicyObservation),
            one(MotorSpeedAction),
        )
        self.observation_delay, self.action_delay = one(ObservationDelay), one(ActionDelay)
        if None in (self.observation, self.action_map, one(RewardSum), one(StepCounter)):
            raise ValueError(
                "collector.kind=fused needs make_env's training stack: the policy maps and episode statistics"
            )
        self.samplers = [t for t in reversed(ts) if isinstance(t, StartSampler)]  # TorchRL's pre-reset order
        self._start(env.reset())

    # ------------------------------------------------------------------ the carrier
    def _start(self, td: TensorDict) -> None:
        """The tensors the next step starts from, from a reset's TensorDict."""
        n = self.n
        truth = torch.zeros(n, 30)
        truth[:, FLAT_ODOMETRY] = td.get(keys.ODOMETRY)  # (the noisy odometry: only its truth part is kept below)
        truth[:, 0:3] = td.get(keys.POSITION)
        truth[:, 3:6] = td.get(keys.LINEAR_VELOCITY)
        truth[:, 12:15] = td.get(keys.ANGULAR_VELOCITY)
        truth[:, FLAT_QUATERNION] = td.get(keys.QUATERNION)
        truth[:, FLAT_MOTORS] = td.get(keys.MOTOR_SPEEDS)
        truth[:, FLAT_GOAL] = td.get(keys.GOAL)
        self.truth, self.odometry, self.obs = truth, td.get(keys.ODOMETRY), td.get(keys.OBSERVATION)
        self.episode_reward, self.step_count = td.get("episode_reward"), td.get("step_count")
        if self.noise is None:  # the unseen columns of the odometry (accelerations, attitude) are the truth
            self.truth[:, FLAT_ODOMETRY] = self.odometry

    def state_dict(self) -> dict:
        """A whole snapshot of collection: the env (physics, generators, every transform's
        buffers) and the carrier; with torch's RNG state (the runner's) a resume is bit-identical."""
        carrier = {"truth": self.truth, "odometry": self.odometry, "observation": self.obs}
        carrier.update(episode_reward=self.episode_reward, step_count=self.step_count)
        return {
            "env_state_dict": self.env.state_dict(),
            "carrier": {k: v.clone() for k, v in carrier.items()},
            "frames": self.frames,
        }

    def load_state_dict(self, state: dict) -> None:
        self.env.load_state_dict(state["env_state_dict"])
        c = state["carrier"]
        self.truth, self.odometry, self.obs = c["truth"].clone(), c["odometry"].clone(), c["observation"].clone()
        self.episode_reward, self.step_count = c["episode_reward"].clone(), c["step_count"].clone()
        self.frames = int(state["frames"])

    def update_policy_weights_(self) -> None:
        """Nothing to do: the collector flies the learner's own network."""

    def shutdown(self) -> None:
        """Nothing to release (the env is the caller's)."""

    # ------------------------------------------------------------------ collection
    def __iter__(self):
        while self.frames < self.total_frames:
            batch = self.collect()
            self.frames += batch.numel()
            yield batch

    @torch.no_grad()
    def collect(self) -> TensorDict:
        """One batch (num_envs, steps), TorchRL's Collector's keys."""
        n, steps, size = self.n, self.steps, self.obs.shape[-1]
        shape = (n, steps)
        root_flat, next_flat = torch.empty(*shape, 30), torch.empty(*shape, 30)
        root_odom, next_odom = torch.empty(*shape, 18), torch.empty(*shape, 18)
        root_obs, next_obs = torch.empty(*shape, size), torch.empty(*shape, size)
        action, loc, scale = torch.empty(*shape, 4), torch.empty(*shape, 4), torch.empty(*shape, 4)
        log_prob = torch.empty(*shape)
        root_ep, next_ep = torch.empty(*shape, 1), torch.empty(*shape, 1)
        root_sc, next_sc = torch.empty(*shape, 1, dtype=torch.long), torch.empty(*shape, 1, dtype=torch.long)
        terminated, truncated = torch.empty(*shape, dtype=torch.bool), torch.empty(*shape, dtype=torch.bool)
        for t in range(steps):
            root_flat[:, t], root_odom[:, t], root_obs[:, t] = self.truth, self.odometry, self.obs
            root_ep[:, t], root_sc[:, t] = self.episode_reward, self.step_count
            a, lp, mu, sigma = self.net.sample(self.obs)
            action[:, t], log_prob[:, t], loc[:, t], scale[:, t] = a, lp, mu, sigma
            flat, term, trunc = self._step(self.action_map.to_command(a))
            terminated[:, t], truncated[:, t] = term, trunc
            next_flat[:, t], next_odom[:, t], next_obs[:, t] = flat, self.odometry, self.obs
            next_ep[:, t], next_sc[:, t] = self.episode_reward, self.step_count
            done = term | trunc
            if bool(done.any()):
                self._restart(done)
        done = terminated | truncated
        no = torch.zeros(*shape, 1, dtype=torch.bool)
        root = {keys.ODOMETRY: root_odom, keys.GOAL: root_flat[..., FLAT_GOAL], keys.STATE: _state(root_flat)}
        nxt = {keys.ODOMETRY: next_odom, keys.GOAL: next_flat[..., FLAT_GOAL], keys.STATE: _state(next_flat)}
        root.update({keys.OBSERVATION: root_obs, "episode_reward": root_ep, "step_count": root_sc})
        nxt.update({keys.OBSERVATION: next_obs, "episode_reward": next_ep, "step_count": next_sc})
        root.update({keys.DONE: no, keys.TERMINATED: no.clone(), keys.TRUNCATED: no.clone()})
        nxt.update({keys.REWARD: next_flat[..., FLAT_REWARD], keys.DONE: done.unsqueeze(-1)})
        nxt.update({keys.TERMINATED: terminated.unsqueeze(-1), keys.TRUNCATED: truncated.unsqueeze(-1)})
        root.update({keys.ACTION: action, "action_log_prob": log_prob, "loc": loc, "scale": scale, "next": nxt})
        return TensorDict(root, batch_size=shape)

    def _step(self, command: torch.Tensor):
        """One control step of the env and every transform, in the stack's order (TorchRL's
        `env.step` and `step_mdp`): the new carrier, and (outputs, terminated, truncated)."""
        applied = command if self.action_delay is None else self.action_delay.push(command)
        flat, terminated, truncated = self.base.advance(applied)
        if self.tdts is not None:
            fire = self.tdts.advance(flat[:, 0:3], flat[:, FLAT_GOAL])
            if self.tdts.as_terminal:
                terminated = terminated | fire
            else:
                truncated = truncated | fire
        if self.jd is not None:
            self.jd.advance()
        if self.css is not None:
            self.css.advance(flat[:, FLAT_REWARD.start], terminated | truncated)
        odometry = flat[:, FLAT_ODOMETRY]
        if self.noise is not None:
            odometry = self.noise.corrupt(odometry)
        if self.observation_delay is not None:
            odometry = self.observation_delay.push(odometry)
        self.obs = self.observation.advance(command, odometry, flat[:, FLAT_GOAL])
        self.truth, self.odometry = flat, odometry
        self.episode_reward = self.episode_reward + flat[:, FLAT_REWARD]
        self.step_count = self.step_count + 1
        return flat, terminated, truncated

    def _restart(self, done: torch.Tensor) -> None:
        """TorchRL's partial reset of the envs in `done` (BFCEnv.reset_envs and the merge of
        `maybe_reset`) on plain tensors."""
        start = None
        for sampler in self.samplers:
            start = sampler.draw_starts(done, start)
        flat = self.base.restart(done, start)
        if self.tdts is not None:
            self.tdts.restart(done)
        odometry = flat[:, FLAT_ODOMETRY]
        if self.noise is not None:
            odometry = self.noise.corrupt(odometry, done)
        if self.observation_delay is not None:
            odometry = self.observation_delay.restart_and_read(done, odometry)
        if self.action_delay is not None:
            self.action_delay.restart_at_hover(done)
        obs = self.observation.restart(done, odometry, flat[:, FLAT_GOAL])
        m = done.unsqueeze(-1)
        self.truth = torch.where(m, flat, self.truth)
        self.odometry = torch.where(m, odometry, self.odometry)
        self.obs = torch.where(m, obs, self.obs)
        self.episode_reward = torch.where(m, 0.0, self.episode_reward)
        self.step_count = torch.where(m, 0, self.step_count)
