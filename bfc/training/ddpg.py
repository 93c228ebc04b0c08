"""DDPG (Lillicrap et al. 2016), which the paper compares with PPO and TRPO (figs. 5-7), from
TorchRL's own pieces: `DDPGLoss` (TD(0) critic target through target networks, actor loss
-Q(s, mu(s))), `SoftUpdate` (Polyak target networks, `algo.ddpg.tau`) and a replay buffer of
`algo.ddpg.buffer_size` transitions. It reads the `algo.ddpg` section (and optim.max_grad_norm /
anneal_lr).

The actor is bfc's Gaussian actor with `model.squash` (tanh on the mean) and its std frozen at
`model.init_std`: sampling it is DDPG's Gaussian exploration noise, and its mean is the
deterministic policy that DDPGLoss trains, `evaluate.py` flies and `policy.pt` stores, so every
tool that reads a PPO policy reads a DDPG one unchanged. JD, CSS and TDTS act on the env's resets
and need nothing from the learner (the paper: they suit any algorithm).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers.samplers import RandomSampler
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP
from torchrl.objectives import DDPGLoss, SoftUpdate, ValueEstimators

from bfc import keys
from bfc.agent import ACTIVATIONS, gaussian_net
from bfc.torchrl_compat import buffer_writer_state, load_buffer_writer_state

# What a transition needs; the rest of the collected tensordict stays out of the buffer.
_KEYS = (
    keys.OBSERVATION,
    keys.ACTION,
    ("next", keys.OBSERVATION),
    ("next", keys.REWARD),
    ("next", keys.DONE),
    ("next", keys.TERMINATED),
)


class QValue(torch.nn.Module):
    """Q(s, a): an MLP on the observation and the action side by side (the observation through
    the actor's ObservationNorm first, when the policy has one)."""

    def __init__(self, obs_size: int, hidden, activation: str = "tanh", obs_norm=None):
        super().__init__()
        object.__setattr__(self, "obs_norm", obs_norm)  # the actor's (not a submodule: see Normalized)
        self.net = MLP(
            in_features=obs_size + 4, out_features=1, num_cells=list(hidden), activation_class=ACTIVATIONS[activation]
        )

    def forward(self, observation: torch.Tensor, action: torch.Tensor) -> torch.Tensor:
        if self.obs_norm is not None:
            observation = self.obs_norm(observation)
        return self.net(torch.cat((observation, action), -1))


class DDPG:
    """The DDPG learner: `update(data, frames)` stores the batch, then takes `algo.ddpg.updates_per_batch`
    gradient steps on minibatches of `algo.ddpg.batch_size` replayed transitions (the interface of
    bfc.training.learners); its critic is its own Q network (the runner's V critic is unused)."""

    def __init__(self, cfg, actor, critic=None):
        a, m = cfg.algo.ddpg, cfg.model
        self.cfg, self.algo = cfg, a
        net = gaussian_net(actor)
        net.log_std.requires_grad_(False)  # fixed exploration noise
        obs_size = net.obs_size
        self.q = TensorDictModule(
            QValue(obs_size, m.critic_hidden, m.activation, net.obs_norm),
            in_keys=[keys.OBSERVATION, keys.ACTION],
            out_keys=["state_action_value"],
        )
        self.loss_module = DDPGLoss(actor, self.q, delay_actor=True, delay_value=True)
        self.loss_module.make_value_estimator(ValueEstimators.TD0, gamma=a.gamma)
        self.target_update = SoftUpdate(self.loss_module, tau=a.tau)
        self.actor_optimizer = torch.optim.Adam(
            [p for p in self.loss_module.actor_network_params.values(True, True) if p.requires_grad],
            lr=a.actor_lr,
            eps=cfg.optim.adam_eps,
        )
        self.critic_optimizer = torch.optim.Adam(
            self.loss_module.value_network_params.values(True, True), lr=a.critic_lr, eps=cfg.optim.adam_eps
        )
        self.optimizers = [self.actor_optimizer, self.critic_optimizer]
        self.buffer = TensorDictReplayBuffer(
            storage=LazyTensorStorage(int(a.buffer_size)), sampler=RandomSampler(), batch_size=int(a.batch_size)
        )
        self.steps = 0

    def update(self, data, frames: int = 0) -> dict[str, float]:
        self.buffer.extend(data.select(*_KEYS).reshape(-1).clone())
        if len(self.buffer) < self.algo.warmup_frames:
            return {}
        sums = {"loss/actor": 0.0, "loss/critic": 0.0, "loss/q_value": 0.0}
        params = [p for p in self.loss_module.parameters() if p.requires_grad]
        for _ in range(int(self.algo.updates_per_batch)):
            batch = self.buffer.sample()
            with set_exploration_type(ExplorationType.DETERMINISTIC):
                value_loss, _ = self.loss_module.loss_value(batch)
                self.critic_optimizer.zero_grad(set_to_none=True)
                value_loss.backward()
                torch.nn.utils.clip_grad_norm_(params, self.cfg.optim.max_grad_norm)
                self.critic_optimizer.step()
                actor_loss, _ = self.loss_module.loss_actor(batch)
                self.actor_optimizer.zero_grad(set_to_none=True)
                actor_loss.backward()
                torch.nn.utils.clip_grad_norm_(params, self.cfg.optim.max_grad_norm)
                self.actor_optimizer.step()
            self.target_update.step()
            self.steps += 1
            sums["loss/actor"] += float(actor_loss.detach())
            sums["loss/critic"] += float(value_loss.detach())
            sums["loss/q_value"] -= float(actor_loss.detach())
        return {k: v / int(self.algo.updates_per_batch) for k, v in sums.items()}

    def state_dict(self) -> dict:
        return {
            "actor_optimizer": self.actor_optimizer.state_dict(),
            "critic_optimizer": self.critic_optimizer.state_dict(),
            "loss": self.loss_module.state_dict(),  # Q network and both target networks
            "buffer": self.buffer_state(),
            "steps": self.steps,
        }

    def buffer_state(self) -> dict:
        """The stored transitions only (not the unwritten rest of the storage) and the writer."""
        n = len(self.buffer)
        transitions = self.buffer.storage.get(torch.arange(n)).to_dict() if n else {}
        return {"transitions": transitions, "size": n, "writer": buffer_writer_state(self.buffer)}

    def load_state_dict(self, state: dict) -> None:
        self.actor_optimizer.load_state_dict(state["actor_optimizer"])
        self.critic_optimizer.load_state_dict(state["critic_optimizer"])
        self.loss_module.load_state_dict(state["loss"])
        b = state["buffer"]
        if b["size"]:
            self.buffer.extend(TensorDict(b["transitions"], batch_size=[b["size"]]))  # not from_dict: no pandas
        load_buffer_writer_state(self.buffer, b["writer"])
        self.steps = int(state["steps"])
