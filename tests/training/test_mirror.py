"""The mirror loss's symmetries hold where it claims them: the airframe's reflections in MuJoCo's
physics, the observation's index-and-sign map, and the loss making a policy symmetric."""

import dataclasses
import math
from types import SimpleNamespace

import pytest
import torch
from tensordict.nn import TensorDictModule

from bfc import keys
from bfc.config import airframe_params, compose
from bfc.evaluation import fly
from bfc.training.mirror import Mirrors, make_mirrors
from bfc.training.ppo_step import PPOStep
from bfc.transforms.observation import PolicyObservation, cos_tilt, observation_size
from tests.training.test_ppo_step import _batch, _columns


def _rates(v, sx, sy):
    """A body rate (or roll, pitch, yaw) seen in the mirror S = diag(sx, sy, 1)."""
    return torch.stack((sy * v[..., 0], sx * v[..., 1], sx * sy * v[..., 2]), -1)


def _vector(v, sx, sy):
    return v * torch.tensor([sx, sy, 1.0], dtype=v.dtype)


def mirrored_start(start, sx, sy):
    """A start (n, 12) seen in the mirror: position and velocity S v, roll, pitch, yaw and body rates."""
    parts = (_vector(start[:, 0:3], sx, sy), _rates(start[:, 3:6], sx, sy), _vector(start[:, 6:9], sx, sy))
    return torch.cat((*parts, _rates(start[:, 9:12], sx, sy)), -1)


def test_an_x_has_both_mirrors_and_the_half_turn_a_plus_the_half_turn_only():
    x, plus = airframe_params("x500").reflections(), airframe_params("hummingbird").reflections()
    assert [(sx, sy) for sx, sy, _ in x] == [(-1, 1), (1, -1), (-1, -1)]
    assert [(sx, sy) for sx, sy, _ in plus] == [(-1, -1)]
    for _, _, motors in x + plus:  # each motor map is its own inverse (a reflection twice is none)
        assert sorted(motors) == [0, 1, 2, 3] and all(motors[motors[j]] == j for j in range(4))


class _Plan(torch.nn.Module):
    """Motor speeds (n, steps, 4) rad/s, one row per control step."""

    def __init__(self, plan):
        super().__init__()
        self.plan, self.step = plan, 0

    def forward(self, odometry, goal):
        self.step += 1
        return self.plan[:, min(self.step - 1, self.plan.shape[1] - 1)]


def _quaternion_matrix(q):
    w, x, y, z = q.unbind(-1)
    return torch.stack(
        (
            1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y),
        ),
        -1,
    ).unflatten(-1, (3, 3))  # fmt: skip


@pytest.mark.parametrize("name", ["x500", "crazyflie", "hummingbird"])
def test_mujoco_flies_the_mirrored_start_and_commands_into_the_mirrored_flight(name):
    """Each reflection AirframeParams claims, flown: a tumbling start and uneven commands, and
    their mirror images, give mirror-image flights (MuJoCo's body, rotors and drag), to float
    rounding without RotorS's rolling moment (it sums |w| whatever the spin, the one term a mirror
    does not keep; the built-ins' leaves them 2 mm apart after 0.4 s, asserted below)."""
    airframe = dataclasses.replace(airframe_params(name), rolling_moment_coefficient=0.0)
    torch.manual_seed(0)
    start = torch.tensor([[0.3, -0.2, 2.0, 0.5, -0.4, 2.0, 0.8, -0.5, 0.3, 1.5, -2.0, 0.7]])
    plan = airframe.hover_speed * (1 + 0.3 * (2 * torch.rand(1, 40, 4) - 1))
    flown = dict(seconds=0.4, control_hz=100.0, airframe=dataclasses.asdict(airframe))
    fly_plan = lambda s, p: fly(TensorDictModule(_Plan(p), [keys.ODOMETRY, keys.GOAL], [keys.ACTION]), s, **flown)
    base = fly_plan(start, plan)
    assert base.get("alive").all()
    for sx, sy, motors in airframe.reflections():
        seen = fly_plan(mirrored_start(start, sx, sy), plan[:, :, list(motors)])
        s = torch.diag(torch.tensor([float(sx), float(sy), 1.0]))
        torch.testing.assert_close(seen.get(keys.POSITION), _vector(base.get(keys.POSITION), sx, sy), atol=1e-5, rtol=0)
        rot = _quaternion_matrix(base.get(keys.QUATERNION))
        torch.testing.assert_close(_quaternion_matrix(seen.get(keys.QUATERNION)), s @ rot @ s, atol=1e-5, rtol=0)
        w = base.get(keys.ANGULAR_VELOCITY)
        torch.testing.assert_close(seen.get(keys.ANGULAR_VELOCITY), _rates(w, sx, sy), atol=1e-4, rtol=0)
    if airframe_params(name).rolling_moment_coefficient > 0:  # the built-in's rolling moment: near, not equal
        sx, sy, motors = airframe.reflections()[0]
        flown["airframe"] = dataclasses.asdict(airframe_params(name))
        near = fly_plan(mirrored_start(start, sx, sy), plan[:, :, list(motors)]).get(keys.POSITION)
        gap = (near - _vector(fly_plan(start, plan).get(keys.POSITION), sx, sy)).abs().max()
        assert gap < 0.01 if sx * sy < 0 else gap < 1e-5  # the half turn keeps it (a rotation)
    # and the mirror the "+" lacks is not one: its flight is not the mirror image
    if airframe.layout == "+":
        seen = fly_plan(mirrored_start(start, -1, 1), plan[:, :, [2, 1, 0, 3]])
        w = _rates(base.get(keys.ANGULAR_VELOCITY), -1, 1)
        assert (seen.get(keys.ANGULAR_VELOCITY) - w).abs().max() > 0.1


@pytest.mark.parametrize("kind", ["heading", "odometry"])
def test_the_observation_of_the_mirrored_world_is_the_mapped_observation(kind):
    n, history = 64, 3
    obs = PolicyObservation(
        n, hover_speed=500.0, include_acceleration=True, position_integral=True, kind=kind, command_history=history
    )
    torch.manual_seed(1)
    odo = torch.randn(n, 18)
    odo[:, 9:12] = torch.rand(n, 3) * torch.tensor([2 * math.pi, math.pi, 2 * math.pi]) - torch.tensor(
        [math.pi, math.pi / 2, math.pi]
    )
    goal = torch.tensor([0.0, 0.0, 1.5]).expand(n, 3)
    last, integral, past = torch.rand(n, 4) * 2 - 1, torch.randn(n, 3) * 0.3, torch.rand(n, history, 4) * 2 - 1
    plain = obs.build(odo, goal, last, integral, past)
    assert plain.shape[-1] == observation_size(kind, True, True, history)
    model = SimpleNamespace(
        observation=kind, include_acceleration=True, position_integral=True, command_history=history
    )
    mirrors = Mirrors(airframe_params("x500"), model, 1.0)
    for (sx, sy, motors), view in zip(airframe_params("x500").reflections(), mirrors.observations(plain), strict=True):
        m = list(motors)
        seen_odo = torch.cat(
            [_vector(odo[:, i : i + 3], sx, sy) for i in (0, 3, 6)]
            + [_rates(odo[:, i : i + 3], sx, sy) for i in (9, 12, 15)],
            -1,
        )
        seen = obs.build(seen_odo, goal, last[:, m], _vector(integral, sx, sy), past[:, :, m])
        torch.testing.assert_close(view, seen, atol=1e-5, rtol=1e-5)


@pytest.mark.parametrize("kind", ["heading", "odometry"])
def test_cos_tilt_reads_each_observations_tilt_from_upright(kind):
    """`loss.mirror_max_tilt` judges a row by cos_tilt of its observation: the tilt of the body z
    axis from the vertical, cos(roll) cos(pitch), whatever the yaw, for bfc's and the paper's."""
    n = 64
    obs = PolicyObservation(n, hover_speed=500.0, position_integral=True, kind=kind, command_history=2)
    torch.manual_seed(2)
    odo = torch.randn(n, 18)
    odo[:, 9:12] = torch.rand(n, 3) * torch.tensor([2 * math.pi, math.pi, 2 * math.pi]) - torch.tensor(
        [math.pi, math.pi / 2, math.pi]
    )
    goal = torch.tensor([0.0, 0.0, 1.5]).expand(n, 3)
    plain = obs.build(odo, goal, torch.zeros(n, 4), torch.zeros(n, 3), torch.zeros(n, 2, 4))
    want = odo[:, 9].cos() * odo[:, 10].cos()
    torch.testing.assert_close(cos_tilt(plain, kind), want, atol=1e-6, rtol=1e-6)
    assert (want < -0.5).any() and (want > 0.5).any()  # upright and upside-down rows both


def test_one_reflection_a_row_is_the_mirror_loss_over_every_reflection_in_expectation():
    """`loss.mirror_reflections=one` mirrors row i through reflection i mod m: over the batch taken
    m times (each row once through each reflection) it is the loss over every reflection, and on
    the batch alone each row's view is its own reflection's."""
    cfg = compose(["env.airframe=x500", "loss.mirror_coeff=2", "loss.mirror_reflections=one"])
    one, every = make_mirrors(cfg), Mirrors(airframe_params("x500"), cfg.model, 2.0)
    torch.manual_seed(0)
    obs, loc, net_out = torch.randn(30, one.index.shape[1]), torch.randn(30, 4), torch.randn(3, 30, 4)
    rows = torch.arange(90)
    reflection = one.reflection(rows)
    assert reflection.tolist() == [0, 1, 2] * 30
    seen = one.observations(obs.repeat_interleave(3, 0), reflection)
    torch.testing.assert_close(seen[0].view(30, 3, -1).transpose(0, 1), every.observations(obs))
    mirrored = net_out.transpose(0, 1).reshape(1, 90, 4)  # row i's mean in reflection i mod 3
    loss_one, grad_one = one.loss(loc.repeat_interleave(3, 0), mirrored, reflection)
    loss_every, grad_every = every.loss(loc, net_out)
    torch.testing.assert_close(loss_one, loss_every)
    torch.testing.assert_close(grad_one.view(30, 3, 4).transpose(0, 1), grad_every)
    assert one.observations(obs, one.reflection(torch.arange(30))).shape == (1, 30, obs.shape[1])


def _asymmetry(probe, net, obs, seen):
    """The mean square of the policy's mean in each mirror against the mirror of its mean."""
    with torch.no_grad():
        return float(probe.loss(net.mean(obs), net.mean(seen))[0])


def test_the_mirror_loss_makes_the_policy_symmetric():
    """PPO steps on a batch with nothing to learn from its advantages: with the mirror loss the
    policy's mean becomes the mirror of itself (the loss falls tenfold), without it it does not."""
    results = {}
    for coeff in (0.0, 1.0):
        cfg, net, actor, critic, loss, flat = _batch(["env.airframe=x500", f"loss.mirror_coeff={coeff}"])
        flat["advantage"] = torch.zeros_like(flat["advantage"])
        probe = Mirrors(airframe_params("x500"), cfg.model, 1.0)
        mirrors = make_mirrors(cfg)
        step = PPOStep(loss, actor, critic, lr=1e-3, adam_eps=1e-8, max_grad_norm=1.0, mirrors=mirrors)
        columns = _columns(step, flat)
        seen = probe.observations(flat["observation"])
        before = _asymmetry(probe, net, flat["observation"], seen)
        for _ in range(150):
            step(*columns, mirrored=None if mirrors is None else step.observe(seen))
        results[coeff] = (before, _asymmetry(probe, net, flat["observation"], seen))
    (off_before, off_after), (on_before, on_after) = results[0.0], results[1.0]
    assert on_after < on_before / 10
    assert off_after > off_before / 3
