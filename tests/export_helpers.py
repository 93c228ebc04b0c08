"""What the ONNX and the C export tests share: the policies, the inputs and the torch reference
(kept apart from test_export.py so that the C tests do not need the onnx extra)."""

from pathlib import Path

import torch

from bfc.agent import PolicySpec, load_policy, save_policy

ROOT = Path(__file__).resolve().parents[1]
PRETRAINED = ROOT / "pretrained" / "policy.pt"
CRAZYFLIE = ROOT / "pretrained" / "crazyflie.pt"  # an "x" airframe, its own hover speed and limits
X500 = ROOT / "pretrained" / "x500.pt"  # a 2.1 kg "x" at 100 Hz, its hover speed 770 rad/s
# On motor speed / hover speed (the speed map's action units): float32 round-off is ~1e-6.
TOLERANCE = 1e-5


def parity_rows(spec):
    """The 2000 rows the export tests compare on: 1000 over the protocol's states and far beyond,
    1000 near hover at the goal, integrals in +-0.5 m s, and for a command-history policy older
    commands (n, k, 4) drawn from the rows' previous ones (None without a history)."""
    hover, top = spec.nominal_airframe.hover_speed, spec.nominal_airframe.max_rotor_speed
    wide = random_inputs(1000, hover, top)
    near = random_inputs(1000, hover, top, seed=3, spread=0.1)
    odometry, goal, previous = (torch.cat(pair) for pair in zip(wide, near, strict=True))
    integral = 0.5 * (2 * torch.rand(2000, 3, generator=torch.Generator().manual_seed(2)) - 1)
    k, history = spec.command_history, None
    if k:
        rows = torch.randint(0, 2000, (2000 * k,), generator=torch.Generator().manual_seed(4))
        history = previous[rows].reshape(2000, k, 4)
    return odometry, goal, previous, integral, history


def hover_speed_difference(got, expected, spec) -> float:
    """max |got - expected| in hover speeds, over the commands where that measures float32 round-off:
    for the thrust map, those at least a tenth of hover (its slope, hover^2 / command, multiplies the
    action-unit round-off by at most 10 there; nearer 0 it grows without bound, and the action
    units measure it instead) or clipped to 0 by both. Asserts that these are most commands."""
    got, expected = torch.as_tensor(got), torch.as_tensor(expected)
    hover = spec.nominal_airframe.hover_speed
    judged = torch.ones_like(expected, dtype=torch.bool)
    if spec.action_map == "thrust":
        judged = (expected >= 0.1 * hover) | ((expected == 0) & (got == 0))
    assert judged.float().mean() > 0.9, f"only {judged.float().mean():.0%} of the commands judged"
    return float((got - expected).abs()[judged].max()) / hover


# Observation constants of a policy of its own (none of them the defaults): the exports must read
# them from its file
SCALED = {
    "position_clip": 0.5,
    "velocity_scale": 0.2,
    "angular_velocity_scale": 0.3,
    "acceleration_scale": 0.1,
    "integral_radius": 0.6,
    "integral_limit": 0.2,
    "integral_scale": 2.0,
    "integral_settled_radius": 2.0,  # wide and fast: many of the parity rows integrate as settled
    "integral_settled_speed": 3.0,
}


def tiny_policy(path, action_map="speed", normalize=False, scales=None):
    """A random 2x16 ELU policy with accelerations in its observation, on a heavier airframe
    (normalize=True: the observation through running statistics, as the paper preset trains;
    scales: observation constants of its own, with the position integral among its inputs)."""
    spec = PolicySpec(
        normalize_observation=normalize,
        include_acceleration=True,
        position_integral=scales is not None,
        observation_scales=scales or {},
        action_map=action_map,
        hidden=(16, 16),
        activation="elu",
        control_hz=250.0,
        airframe={"body_mass": 0.8, "max_rotor_speed": 900.0},
    )
    torch.manual_seed(0)
    net = spec.make_net()
    with torch.no_grad():  # undo the near-zero last layer, so the outputs spread over the action range
        for p in net.mlp.parameters():
            p.normal_(0.0, 0.2)
        set_statistics(net)
    save_policy(path, spec, net)
    return path


def set_statistics(net, seed=5):
    """Give an ObservationNorm (if the net has one) statistics far from its start, some
    observations clipped at its bound."""
    if net.obs_norm is not None:
        g = torch.Generator().manual_seed(seed)
        size = net.obs_norm.mean.shape[0]
        net.obs_norm.update(torch.randn(500, size, generator=g) * (0.05 + torch.rand(size, generator=g)) + 0.3)


def random_inputs(n, hover, max_speed, seed=0, spread=1.0):
    """Odometry around the protocol's states (and beyond; `spread` < 1 keeps it nearer them), any
    goal, previous commands over [0, max]."""
    g = torch.Generator().manual_seed(seed)
    scale = spread * torch.tensor([2.0, 2, 2, 2, 2, 2, 5, 5, 5, 0.7, 0.7, 3.14, 3, 3, 3, 20, 20, 20])
    odometry = (2 * torch.rand(n, 18, generator=g) - 1) * scale
    odometry[:, 2] += 1.5
    goal = torch.tensor([0.0, 0.0, 1.5]) + 0.5 * spread * torch.randn(n, 3, generator=g)
    previous = hover * (0.6 + 0.8 * torch.rand(n, 4, generator=g))
    previous[: n // 10] = max_speed * torch.rand(n // 10, 4, generator=g)  # some far from hover
    previous[n // 10 : n // 5] = hover  # after a reset
    return odometry, goal, previous


def torch_reference(policy_path, odometry, goal, previous, integral=None, history=None):
    """What the env + the deterministic torch actor command: PolicyObservation.integrate and
    .build, the actor's mean, MotorSpeedAction.to_command, the env's clip to [0, max]
    (`history`: the older commands (n, k, 4) rad/s of a command-history policy)."""
    spec, net = load_policy(policy_path)
    action, observation = spec.make_action_map(), spec.make_observation_map(len(odometry))
    if spec.position_integral:
        integral = observation.integrate(integral, odometry, goal)
    if spec.command_history:
        history = action.to_action(history).clamp(-1, 1)
    obs = observation.build(odometry, goal, action.to_action(previous).clamp(-1, 1), integral, history)
    with torch.no_grad():
        mean = net.mean(obs)
    return action.to_command(mean).clamp(0.0, action.max_speed), spec
