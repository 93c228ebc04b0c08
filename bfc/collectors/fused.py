"""bfc's own collector: the batches TorchRL's Collector gives, in one batched pass per step.

TorchRL's `Collector` over the env `make_env` builds spends most of a step in per-step machinery
(a TensorDict per call, the transforms walked one by one through their hooks, the partial reset's
select and merge). `FusedCollector` runs the env's pipeline instead (bfc.transforms.pipeline: the
same stages the hooks call, on plain tensors): the actor's `sample`, one `Pipeline.step`, and for
the envs that are done one `Pipeline.restart`. It writes every step straight into the batch's
preallocated tensors and builds one TensorDict per batch, with the same keys, shapes and values
as TorchRL's Collector gives on the same env and seed (tests/collectors/test_pipeline.py, bit for
bit). It runs any stack of bfc's own transforms; a stack with any other transform needs
`collector.kind=torchrl`.
"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from torchrl.envs import RewardSum, StepCounter

from bfc import keys
from bfc.agent import GaussianActor
from bfc.config import check_frames_per_batch
from bfc.envs.quadrotor import FLAT_GOAL, FLAT_REWARD, FLAT_SIZE, state_views
from bfc.transforms import PolicyObservation
from bfc.transforms.pipeline import Pipeline, StepState, UnknownStage

_STATISTICS = (RewardSum, StepCounter)  # TorchRL's episode statistics: the collector keeps them


class FusedCollector:
    """Batches of shape (num_envs, frames_per_batch / num_envs) from `env` (a `make_env` env)
    with the policy network `net` (shared: no weight copy is needed after an update)."""

    def __init__(self, env, net: GaussianActor, frames_per_batch: int, total_frames: int):
        try:
            self.pipeline = Pipeline.of(env, ignore=_STATISTICS)
        except UnknownStage as e:
            raise ValueError(
                f"collector.kind=fused runs bfc's own transforms only; {e} needs collector.kind=torchrl"
            ) from None
        self.env, self.net, self.base = env, net, env.base_env
        self.n = self.base.num_envs
        check_frames_per_batch(frames_per_batch, self.n)
        self.steps, self.total_frames, self.frames = frames_per_batch // self.n, int(total_frames), 0
        ts = list(env.transform)
        if not any(isinstance(t, PolicyObservation) for t in ts) or not all(
            any(isinstance(t, cls) for t in ts) for cls in _STATISTICS
        ):
            raise ValueError(
                "collector.kind=fused needs make_env's training stack: the policy maps and episode statistics"
            )
        self.state = self.pipeline.start()
        self.episode_reward = torch.zeros(self.n, 1)
        self.step_count = torch.zeros(self.n, 1, dtype=torch.long)

    def state_dict(self) -> dict:
        """A whole snapshot of collection: the env (physics, generators, every transform's
        buffers) and the carrier; with torch's RNG state (the runner's) a resume is bit-identical."""
        s = self.state
        carrier = {"truth": s.truth, "odometry": s.odometry, "observation": s.observation}
        carrier.update(episode_reward=self.episode_reward, step_count=self.step_count)
        return {
            "env_state_dict": self.env.state_dict(),
            "carrier": {k: v.clone() for k, v in carrier.items()},
            "frames": self.frames,
        }

    def load_state_dict(self, state: dict) -> None:
        self.env.load_state_dict(state["env_state_dict"])
        c = state["carrier"]
        self.state = StepState()
        self.state.set_truth(c["truth"].clone())
        self.state.odometry, self.state.observation = c["odometry"].clone(), c["observation"].clone()
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
        state, n, steps = self.state, self.n, self.steps
        size, shape = state.observation.shape[-1], (n, steps)
        root_flat, next_flat = torch.empty(*shape, FLAT_SIZE), torch.empty(*shape, FLAT_SIZE)
        width = state.odometry.shape[-1]
        root_odom, next_odom = torch.empty(*shape, width), torch.empty(*shape, width)
        root_obs, next_obs = torch.empty(*shape, size), torch.empty(*shape, size)
        action, loc, scale = torch.empty(*shape, 4), torch.empty(*shape, 4), torch.empty(*shape, 4)
        log_prob = torch.empty(*shape)
        root_ep, next_ep = torch.empty(*shape, 1), torch.empty(*shape, 1)
        root_sc, next_sc = torch.empty(*shape, 1, dtype=torch.long), torch.empty(*shape, 1, dtype=torch.long)
        terminated, truncated = torch.empty(*shape, dtype=torch.bool), torch.empty(*shape, dtype=torch.bool)
        for t in range(steps):
            root_flat[:, t], root_odom[:, t], root_obs[:, t] = state.truth, state.odometry, state.observation
            root_ep[:, t], root_sc[:, t] = self.episode_reward, self.step_count
            a, lp, mu, sigma = self.net.sample(state.observation)
            action[:, t], log_prob[:, t], loc[:, t], scale[:, t] = a, lp, mu, sigma
            state.action = a
            self.pipeline.step(state)
            terminated[:, t], truncated[:, t] = state.terminated, state.truncated
            next_flat[:, t], next_odom[:, t], next_obs[:, t] = state.truth, state.odometry, state.observation
            self.episode_reward = self.episode_reward + state.truth[:, FLAT_REWARD]
            self.step_count = self.step_count + 1
            next_ep[:, t], next_sc[:, t] = self.episode_reward, self.step_count
            done = state.terminated | state.truncated
            if bool(done.any()):
                self.pipeline.restart(state, done)
                m = done.unsqueeze(-1)
                self.episode_reward = torch.where(m, 0.0, self.episode_reward)
                self.step_count = torch.where(m, 0, self.step_count)
        done = terminated | truncated
        no = torch.zeros(*shape, 1, dtype=torch.bool)
        root = {keys.ODOMETRY: root_odom, keys.GOAL: root_flat[..., FLAT_GOAL], keys.STATE: state_views(root_flat)}
        nxt = {keys.ODOMETRY: next_odom, keys.GOAL: next_flat[..., FLAT_GOAL], keys.STATE: state_views(next_flat)}
        root.update({keys.OBSERVATION: root_obs, "episode_reward": root_ep, "step_count": root_sc})
        nxt.update({keys.OBSERVATION: next_obs, "episode_reward": next_ep, "step_count": next_sc})
        root.update({keys.DONE: no, keys.TERMINATED: no.clone(), keys.TRUNCATED: no.clone()})
        nxt.update({keys.REWARD: next_flat[..., FLAT_REWARD], keys.DONE: done.unsqueeze(-1)})
        nxt.update({keys.TERMINATED: terminated.unsqueeze(-1), keys.TRUNCATED: truncated.unsqueeze(-1)})
        root.update({keys.ACTION: action, "action_log_prob": log_prob, "loc": loc, "scale": scale, "next": nxt})
        return TensorDict(root, batch_size=shape)
