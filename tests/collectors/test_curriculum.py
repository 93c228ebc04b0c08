"""The difficulty curriculum widens JD's starts and the airframe randomisation with the frames."""

import math

import pytest
import torch

from bfc import keys
from bfc.collectors.curriculum import Curriculum
from bfc.factory import find_transform, make_env
from bfc.transforms import ActionDelay, JumpingDistribution, ObservationDelay
from bfc.transforms.pipeline import StepState
from tests.training.helpers import compose_cfg

WIDE = [
    "extras=none",
    "env.num_envs=512",
    "jd.roll_range=[-180,180]",
    "jd.angular_velocity_range=[-100,100]",
    "env.randomize.mass=[0.5,1.5]",
    "env.randomize.external_force=2.0",
    "curriculum.frames=1000",
    "curriculum.start=0.25",
]


def spreads(env):
    td = env.reset()
    base = env.base_env
    roll = td[keys.ODOMETRY][:, 9].abs().max().item()
    spin = td[keys.ANGULAR_VELOCITY].abs().max().item()
    mass = base.airframe_scale["mass"]
    return roll, spin, (mass - 1).abs().max().item(), base.external_force.norm(dim=-1).max().item()


def test_scale_rises_linearly_from_start_to_one_and_is_off_by_default():
    cfg = compose_cfg(WIDE)
    env = make_env(cfg, seed=0)
    cur = Curriculum(cfg, env, find_transform(env, JumpingDistribution))
    assert [cur.scale(f) for f in (0, 500, 1000, 10**9)] == pytest.approx([0.25, 0.625, 1.0, 1.0])
    off = compose_cfg(["extras=none"])
    assert Curriculum(off, env).scale(0) == 1.0


def test_starts_and_airframes_widen_with_the_scale():
    cfg = compose_cfg(WIDE)
    env = make_env(cfg, seed=0)
    cur = Curriculum(cfg, env, find_transform(env, JumpingDistribution))
    cur.apply(0)  # a quarter of every range
    roll, spin, mass, wind = spreads(env)
    assert math.radians(35) < roll <= math.radians(45) + 1e-5
    assert math.radians(20) < spin <= math.radians(25) + 1e-5
    assert 0.1 < mass <= 0.125 + 1e-9 and 0.3 < wind <= 0.5 + 1e-6
    cur.apply(1000)  # all of it
    roll, spin, mass, wind = spreads(env)
    assert roll > math.radians(170) and spin > math.radians(90) and mass > 0.45 and wind > 1.8
    env.close()


def test_a_resumed_run_flies_the_curriculum_where_it_left_off(tmp_path):
    from bfc.training.runner import Runner
    from tests.training.helpers import TINY

    cfg = compose_cfg([*TINY, "collector.workers=0", "curriculum.frames=4096", "curriculum.start=0.5"])
    runner = Runner(cfg, tmp_path)
    world = runner.collection
    assert world.env.base_env.randomize_scale == 0.5 and world.jd.range_scale == 0.5
    assert world.jd.inverted_scale == 0.0  # JD's upside-down share grows with the progress
    runner.learn()  # 2048 frames: the last batch started at 1536 (scale 0.6875)
    assert world.jd.range_scale == pytest.approx(0.6875) and world.jd.inverted_scale == pytest.approx(0.375)
    runner.close()
    resumed = Runner(
        compose_cfg(
            [
                *TINY,
                "collector.workers=0",
                "collector.total_frames=4096",
                "curriculum.frames=4096",
                "curriculum.start=0.5",
            ]
        ),
        tmp_path,
    )
    resumed.load(torch.load(tmp_path / "checkpoints" / "last.pt", weights_only=True))
    world = resumed.collection  # where the next batch (from 2048) is flown
    assert world.jd.range_scale == pytest.approx(0.75) and world.jd.inverted_scale == pytest.approx(0.5)
    resumed.close()


@pytest.mark.parametrize("grow", [True, False])
def test_delays_grow_in_with_the_curriculum_unless_told_not_to(grow):
    """latency.curriculum: no delay at the first frame, half way half of each range, then all of it
    (a fixed delay as well as a range); false: the configured delays from the first frame."""
    from bfc.collectors.collection import LocalCollection

    cfg = compose_cfg(
        [
            "extras=none",
            "env.num_envs=64",
            "collector.frames_per_batch=64",
            "curriculum.frames=1000",
            "latency.observation_steps=[2,6]",
            "latency.action_steps=3",
            f"latency.curriculum={str(grow).lower()}",
        ]
    )
    local = LocalCollection(cfg, None, 64)  # the curriculum applied before the first reset
    obs_delay, act_delay = (find_transform(local.env, c) for c in (ObservationDelay, ActionDelay))
    mask = torch.ones(64, dtype=torch.bool)

    def drawn():
        obs_delay.refill(mask, torch.zeros(64, 18))
        act_delay.restart(StepState(), mask)
        return obs_delay.delay.min().item(), obs_delay.delay.max().item(), act_delay.delay.unique().tolist()

    assert drawn() == ((0, 0, [0]) if grow else (2, 6, [3]))
    local.curriculum.apply(500)
    assert drawn() == ((1, 3, [2]) if grow else (2, 6, [3]))  # 1.5 rounds to 2
    local.curriculum.apply(1000)
    assert drawn() == (2, 6, [3])
    local.env.close()
