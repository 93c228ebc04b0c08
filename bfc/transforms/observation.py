"""The policy's input, built from what sensors report (`"odometry"`) and the goal.

Goal-relative position (so one policy flies to any goal and follows waypoints), the attitude as
a rotation matrix (continuous, unlike Euler angles), velocities, and the previous motor command.
Position and velocity are expressed in the heading frame (the world frame turned by the yaw),
and the attitude is roll and pitch only: the task is symmetric in yaw, and a policy that sees
world-frame vectors learns a preferred heading and turns to it, flipping over when it starts
near yaw +-180 deg (measured: 15-25% crashes on the protocol's starts).
The scales bring each part to order 1; they are fixed, so a policy file needs no running
statistics. Accelerations (finite differences, noisy) are left out by default.

`kind="odometry"` is the paper's observation instead (for `+preset=paper`): the 18 odometry
numbers as they come, the position made relative to the goal, no previous command, no scaling.

`position_integral=True` adds the integral of the position error (3 numbers, heading frame): a
memoryless policy cannot tell a heavier body, a weaker motor or wind from its own error, so it
hovers off the goal by the offset such a disturbance needs; with the integral it can remove it,
as the integral term of a PID does. It integrates within `integral_radius` of the goal, and
farther out (within `integral_settled_radius`) only while the drone is settled, slower than
`integral_settled_speed`: no wind-up while flying in from afar, yet a push that holds the drone
still beyond the radius (twice the trained wind holds a policy about 35 cm off) is integrated away.
It is clipped to +-`integral_limit` (m s); it restarts with each episode, from the error of the
episode's first odometry (so at every step it includes the current error: the same recursion the
exported policies run, bfc/agent/onnx.py).

`command_history=k` adds the k commands before the previous one (4 k more inputs, newest first, in
the policy's action space, hover after a reset): with odometry that arrives late or commands that
apply late, what the drone does now depends on commands the policy gave several steps ago; a
memoryless policy cannot tell which delay it flies under, one that sees its recent commands can
predict through it (the exports carry the history as state, as they carry the integral).
"""

from __future__ import annotations

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded

from bfc import keys
from bfc.transforms._base import BatchedTransform, StepState, check, reset_mask

OBSERVATIONS = ("heading", "odometry")
# The observation's scales, clip and integral constants: a policy's own (PolicySpec stores them in
# its file, the exports read them from there); these are what a new policy gets.
OBSERVATION_SCALES = {  # keys.OBSERVATION_SCALE_NAMES, in that order
    "position_clip": 3.0,  # m: the goal-relative position's clip
    "velocity_scale": 0.5,
    "angular_velocity_scale": 0.1,
    "acceleration_scale": 0.05,
    "integral_radius": 0.3,  # m: integrate within this of the goal
    "integral_limit": 0.5,  # m s: the integral's clip
    "integral_scale": 4.0,
    # m, m/s: beyond integral_radius, integrate while settled (slower than this) within this radius
    "integral_settled_radius": 1.0,
    "integral_settled_speed": 0.2,
}


def observation_size(
    kind: str = "heading", include_acceleration: bool = False, position_integral: bool = False, command_history: int = 0
) -> int:
    """How many numbers the observation of this kind has (the policy network's input size)."""
    check(kind in OBSERVATIONS, "model.observation", " or ".join(OBSERVATIONS), kind)
    check_history(command_history)
    base = 18 if kind == "odometry" else 22 + (6 if include_acceleration else 0)
    return base + (3 if position_integral else 0) + 4 * command_history


def mirror_map(
    kind: str,
    include_acceleration: bool,
    position_integral: bool,
    command_history: int,
    sx: int,
    sy: int,
    motors,
) -> tuple[torch.Tensor, torch.Tensor]:
    """(index, sign): the observation of the world seen through S = diag(sx, sy, 1) about the goal's
    vertical (an AirframeParams.reflections() entry) is `obs[..., index] * sign`. Vectors, world or
    heading frame, go to S v (the yaw goes to sx sy yaw, which turns the heading frame alike); the
    attitude to S R S (roll sy roll, pitch sx pitch); body rates, a pseudovector, to det(S) S w;
    motor-space inputs swap motors as `motors` says."""
    s = (sx, sy, 1)
    vector, rates = (range(3), s), (range(3), (sy, sx, sx * sy))
    motor = (list(motors), (1, 1, 1, 1))
    if kind == "odometry":
        parts = [vector, vector, vector, rates, rates, rates]  # position, velocity, acceleration, rpy, w, dw
    else:
        matrix = (range(9), [s[i] * s[j] for i in range(3) for j in range(3)])
        parts = [vector, matrix, vector, rates, motor]
        parts += [vector, rates] if include_acceleration else []
    parts += [vector] if position_integral else []
    parts += [motor] * command_history
    idx, sign, at = [], [], 0
    for order, signs in parts:  # each part's own indices, shifted to where it starts
        idx += [at + i for i in order]
        sign += list(signs)
        at += len(order)
    return torch.tensor(idx), torch.tensor(sign, dtype=torch.float32)


def cos_tilt(obs: torch.Tensor, kind: str) -> torch.Tensor:
    """(...,): the cosine of each raw (unnormalised) observation's tilt from upright, read from its
    attitude: bfc's rotation matrix's last element, or the paper's roll and pitch."""
    if kind == "odometry":
        return obs[..., 9].cos() * obs[..., 10].cos()  # position, velocity, acceleration, then roll, pitch
    return obs[..., 11]  # the position (3), then Ry(pitch) Rx(roll) row by row: its (3, 3) is cos tilt


def check_history(command_history) -> None:
    whole = isinstance(command_history, int) and not isinstance(command_history, bool)
    check(whole and 0 <= command_history <= 50, "model.command_history", "a whole number 0-50", command_history)


def to_heading_frame(v: torch.Tensor, yaw: torch.Tensor, cos_sin=None) -> torch.Tensor:
    """World vectors (..., 3) in the frame turned by `yaw` about z (`cos_sin`: the yaw's cosine
    and sine, when the caller turns several vectors by the same yaw)."""
    c, s = cos_sin if cos_sin is not None else (yaw.cos(), yaw.sin())
    return torch.stack(heading_columns(*v.unbind(-1), c, s), -1)


def heading_columns(x, y, z, c, s) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """The columns of a world vector (x, y, z) turned by the yaw whose cosine and sine are c, s."""
    return c * x + s * y, c * y - s * x, z


class PolicyObservation(BatchedTransform):
    def __init__(
        self,
        num_envs: int,
        hover_speed: float,
        include_acceleration: bool = False,
        command_to_action=None,
        position_integral: bool = False,
        dt: float = 0.01,
        kind: str = "heading",
        command_history: int = 0,
        scales: dict | None = None,
    ):
        """scales: any of OBSERVATION_SCALES's constants (a policy's own, from its PolicySpec);
        the rest are OBSERVATION_SCALES's."""
        super().__init__(num_envs, in_keys=[keys.ODOMETRY, keys.GOAL], out_keys=[keys.OBSERVATION])
        check(hover_speed > 0, "hover_speed", "> 0", hover_speed)
        given = dict(scales or {})
        unknown = sorted(set(given) - set(OBSERVATION_SCALES))
        check(not unknown, "observation scales", f"among {', '.join(OBSERVATION_SCALES)}", unknown)
        for name, default in OBSERVATION_SCALES.items():
            value = float(given.get(name, default))
            check(value > 0, name, "> 0", value)
            setattr(self, name, value)
        self.hover_speed = float(hover_speed)
        self.include_acceleration = bool(include_acceleration)
        self.position_integral = bool(position_integral)
        check(dt > 0, "dt", "> 0", dt)
        self.dt = float(dt)
        self.kind = kind
        self.size = observation_size(kind, include_acceleration, position_integral, command_history)
        self.command_history = int(command_history)
        # the previous command is shown in the policy's own action space (MotorSpeedAction.to_action)
        self.command_to_action = command_to_action or (lambda command: command / self.hover_speed - 1.0)
        self.register_buffer("last_action", torch.zeros(num_envs, 4))
        self.register_buffer("integral", torch.zeros(num_envs, 3))  # world frame, m s
        # the commands before the previous one, newest first (policy's action space)
        self.register_buffer("history", torch.zeros(num_envs, self.command_history, 4))

    def integrate(self, integral: torch.Tensor, odometry: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The position-error integral after one more control step (world frame)."""
        error = odometry[..., 0:3] - goal
        distance2 = error.square().sum(-1, keepdim=True)
        settled = odometry[..., 3:6].square().sum(-1, keepdim=True) < self.integral_settled_speed**2
        near = (distance2 < self.integral_radius**2) | (settled & (distance2 < self.integral_settled_radius**2))
        near = near.to(error.dtype)
        return (integral + near * error * self.dt).clamp(-self.integral_limit, self.integral_limit)

    def build(
        self,
        odometry: torch.Tensor,
        goal: torch.Tensor,
        last_action: torch.Tensor,
        integral: torch.Tensor | None = None,
        history: torch.Tensor | None = None,
    ) -> torch.Tensor:
        if self.position_integral and integral is None:
            raise ValueError("this observation has a position_integral: pass the integral (N, 3)")
        if self.command_history and history is None:
            raise ValueError(f"this observation has a command_history: pass the history (N, {self.command_history}, 4)")
        older = [history.flatten(-2)] if self.command_history else []
        if self.kind == "odometry":
            parts = [odometry[..., 0:3] - goal, odometry[..., 3:18]]
            if self.position_integral:
                parts.append(to_heading_frame(integral, odometry[..., 11]) * self.integral_scale)
            return torch.cat(parts + older, -1)
        # Few, wide ops (this runs once per control step on the whole batch, and a torch op costs
        # about as much on 100 rows as on 2,000): the trigonometry of roll, pitch and yaw at once,
        # and the goal-relative position, the velocity and the integral turned together.
        cos, sin = odometry[..., 9:12].cos(), odometry[..., 9:12].sin()
        cr, cp, c = cos.unbind(-1)
        sr, sp, s = sin.unbind(-1)
        vectors = [odometry[..., 0:3] - goal, odometry[..., 3:6]] + ([integral] if self.position_integral else [])
        x, y, z = torch.stack(vectors, -2).unbind(-1)  # (..., k) each
        c, s = c.unsqueeze(-1), s.unsqueeze(-1)
        turned = torch.stack(heading_columns(x, y, z, c, s), -1)  # (..., k, 3), heading frame
        parts = [
            turned[..., 0, :].clamp(-self.position_clip, self.position_clip),  # goal-relative position
            # the rotation matrix of roll and pitch only (Ry(pitch) Rx(roll)), row by row
            torch.stack((cp, sp * sr, sp * cr, torch.zeros_like(cr), cr, -sr, -sp, cp * sr, cp * cr), -1),
            turned[..., 1, :] * self.velocity_scale,
            odometry[..., 12:15] * self.angular_velocity_scale,
            last_action,
        ]
        if self.include_acceleration:
            parts += [odometry[..., 6:9] * self.acceleration_scale, odometry[..., 15:18] * self.acceleration_scale]
        if self.position_integral:
            parts.append(turned[..., 2, :] * self.integral_scale)
        return torch.cat(parts + older, -1)

    def shift(self, history: torch.Tensor, last_action: torch.Tensor) -> torch.Tensor:
        """The history one step on: the previous action becomes its newest entry."""
        return torch.cat([last_action.unsqueeze(-2), history[..., :-1, :]], -2)

    def advance(self, state: StepState) -> None:
        """The observation of the step: the command as commanded (not as applied late), the odometry as seen."""
        state.observation = self.observe_step(state.command, state.odometry, state.goal)

    def restart(self, state: StepState, mask: torch.Tensor) -> None:
        state.observation = self.observe_restart(mask, state.odometry, state.goal)

    def observe_step(self, command: torch.Tensor, odometry: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """One control step: remember the command just flown (N, 4, rad/s) as the previous action,
        integrate the position error, and return the observation (N, size) of the new odometry."""
        if self.command_history:
            self.history.copy_(self.shift(self.history, self.last_action))
        self.last_action.copy_(self.command_to_action(command).clamp(-1, 1))
        if self.position_integral:
            self.integral.copy_(self.integrate(self.integral, odometry, goal))
        return self.build(odometry, goal, self.last_action, self.integral, self.history)

    def observe_restart(self, mask: torch.Tensor, odometry: torch.Tensor, goal: torch.Tensor) -> torch.Tensor:
        """The envs in `mask` (N,) start a new episode: no previous action, and the integral of
        the error of their first odometry alone (the integral always includes the current
        error, from the first step on, as the exported graph computes it); the observation
        (N, size) of every env."""
        mask = mask.unsqueeze(-1)
        self.last_action.masked_fill_(mask, 0.0)
        if self.command_history:
            self.history.masked_fill_(mask.unsqueeze(-1), 0.0)
        if self.position_integral:
            first = self.integrate(torch.zeros_like(self.integral), odometry, goal)
            self.integral.copy_(torch.where(mask, first, self.integral))
        return self.build(odometry, goal, self.last_action, self.integral, self.history)

    def _call(self, td: TensorDictBase) -> TensorDictBase:
        # build() writes a new tensor: the buffers themselves are never handed out
        obs = self.build(td.get(keys.ODOMETRY), td.get(keys.GOAL), self.last_action, self.integral, self.history)
        td.set(keys.OBSERVATION, obs)
        return td

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        # The action here is the motor command in rad/s (inverse transforms already ran).
        state = StepState(command=tensordict.get(keys.ACTION), odometry=next_tensordict.get(keys.ODOMETRY))
        state.goal = next_tensordict.get(keys.GOAL)
        self.advance(state)
        return next_tensordict.set(keys.OBSERVATION, state.observation)

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        state = StepState(odometry=tensordict_reset.get(keys.ODOMETRY), goal=tensordict_reset.get(keys.GOAL))
        self.restart(state, reset_mask(tensordict, self.num_envs))
        return tensordict_reset.set(keys.OBSERVATION, state.observation)

    def transform_observation_spec(self, observation_spec: Composite) -> Composite:
        observation_spec[keys.OBSERVATION] = Unbounded(shape=(self.num_envs, self.size), dtype=torch.float32)
        return observation_spec
