"""evaluate.py video=true: MP4 and GIF of chosen flights rendered by MuJoCo, and its clean failures."""

import importlib.util
import json
import math
import os

import numpy as np
import pytest
import torch

from bfc.evaluation.suites import CONDITIONS, any_starts
from bfc.evaluation.video import check_options, pick_starts, slug, start_tilt_degrees
from tests.evaluation.scripts import SHIPPED, evaluate, run_script

needs_extra = pytest.mark.skipif(
    importlib.util.find_spec("av") is None, reason="the video extra (PyAV) is not installed: pip install -e '.[video]'"
)


def read_mp4(path):
    import av

    with av.open(str(path)) as container:
        return [f.to_ndarray(format="rgb24") for f in container.decode(video=0)]


def read_gif(path):
    from PIL import Image, ImageSequence

    with Image.open(path) as im:
        return [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(im)]


@needs_extra
def test_two_flights_make_an_mp4_and_a_gif_with_the_frames_asked_for(tmp_path):
    fps, seconds = 10, 2.0  # long enough for the first flight to reach the goal: both in the last frame
    r = evaluate(
        f"policy={SHIPPED}",
        "eval.num_starts=2",
        f"eval.seconds={seconds}",
        "figures=false",
        "video=true",
        f"video_fps={fps}",
        "video_width=160",
        "video_height=120",
        out=tmp_path,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert json.loads((tmp_path / "results.json").read_text())["starts"] == 2
    per_flight = math.floor(seconds * fps) + 1  # one frame each 1/fps s, the release and the end included
    mp4 = read_mp4(tmp_path / "video.mp4")
    assert len(mp4) == 2 * per_flight and mp4[0].shape == (120, 160, 3)
    gif = read_gif(tmp_path / "video.gif")  # 10 fps: under the GIF's 15, so every frame
    assert len(gif) == 2 * per_flight and gif[0].shape == (120, 160, 3)
    # the first flight's end: its trace and the goal are drawn. Read from the MP4, between the
    # overlay's lines of text (its "in the goal box" is green too): a drone at the goal hides the
    # ball, and the GIF's palette moves the translucent box's green out of the test's reach
    last = mp4[per_flight - 1][24:100].astype(int)
    r_, g_, b_ = last[..., 0], last[..., 1], last[..., 2]
    orange = (r_ > 150) & (r_ > b_ + 60) & (g_ > 70) & (g_ < 170)
    green = (g_ > r_ + 40) & (g_ > b_ + 40)
    assert orange.sum() > 5 and green.sum() > 5
    assert "video frames rendered" in r.stdout


def test_without_a_renderer_the_numbers_are_written_and_one_line_says_what_to_install(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    env["MUJOCO_GL"] = "no-such-backend"  # would make `import mujoco` fail: bfc turns it off instead
    r = evaluate(f"policy={SHIPPED}", "eval.num_starts=2", "eval.seconds=1", "video=true", out=tmp_path, env=env)
    if importlib.util.find_spec("av") is None:  # without the extra it stops earlier, with its own line
        assert r.returncode == 2 and r.stderr.strip().startswith("error: video=true needs the video extra")
        return
    assert r.returncode == 2, r.stderr[-2000:]
    lines = r.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("error: video=true needs an OpenGL renderer")
    assert "MUJOCO_GL=no-such-backend" in lines[0] and "apt-get install" in lines[0]
    assert json.loads((tmp_path / "results.json").read_text())["starts"] == 2
    assert not (tmp_path / "video.mp4").exists()


@needs_extra
def test_robust_films_the_most_tilted_starts_of_every_row(tmp_path):
    r = evaluate(
        "suite=robust",
        f"policy={SHIPPED}",
        "baselines=[]",
        "eval.num_starts=3",
        "eval.seconds=2",
        "eval.hold_seconds=0.5",
        "video=true",
        "video_starts=1",
        "video_seconds=0.3",
        "video_fps=10",
        "video_width=64",
        "video_height=48",
        out=tmp_path,
    )
    assert r.returncode == 0, r.stderr[-2000:]
    assert (tmp_path / "robust.json").exists()
    for name in CONDITIONS:
        frames = read_mp4(tmp_path / f"video_{slug(name)}.mp4")
        assert len(frames) == math.floor(0.3 * 10) + 1 and frames[0].shape == (48, 64, 3)
        assert (tmp_path / f"video_{slug(name)}.gif").exists()


def test_picks_the_most_tilted_starts_or_the_first():
    starts = any_starts(50, seed=0)
    tilt = start_tilt_degrees(starts)
    chosen = pick_starts(starts, 3, "tilted")
    assert tilt[chosen].min() >= tilt[[i for i in range(50) if i not in chosen]].max()
    assert tilt[chosen].min() > 150  # half the 'any' starts are upside down: the hardest are near 180
    assert pick_starts(starts, 3, "first") == [0, 1, 2]
    assert pick_starts(starts[:2], 5, "first") == [0, 1]
    level = torch.zeros(1, 12)
    assert start_tilt_degrees(level).item() == pytest.approx(0.0, abs=1e-6)


def test_row_names_make_distinct_file_names():
    names = [slug(n) for n in CONDITIONS]
    assert len(set(names)) == len(names) and slug("mass +30%") == "mass_plus30"


@pytest.mark.parametrize(
    "kw, key",
    [
        ({"camera": "drone"}, "video_camera"),
        ({"pick": "random"}, "video_pick"),
        ({"width": 101}, "video_width"),
        ({"fps": 0}, "video_fps"),
        ({"starts": 0}, "video_starts"),
        ({"seconds": -1.0}, "video_seconds"),
    ],
)
def test_bad_video_options_name_the_key(kw, key):
    good = {"fps": 20, "width": 480, "height": 360, "starts": 4, "camera": "chase", "pick": "tilted", "seconds": 5.0}
    check_options(**good)
    with pytest.raises(ValueError, match=key):
        check_options(**{**good, **kw})


def test_video_keys_without_video_are_rejected(tmp_path):
    r = evaluate(f"policy={SHIPPED}", "video_fps=5", out=tmp_path)
    assert r.returncode == 2 and r.stderr.strip() == "error: video_fps only apply with video=true"


TINY_TRAINING = [
    "env.num_envs=16",
    "collector.frames_per_batch=512",
    "collector.total_frames=1024",
    "collector.workers=0",
    "loss.num_minibatches=2",
    "eval.num_starts=2",
    "eval.seconds=1",
    "eval.hold_seconds=0.2",
    "eval.interval_frames=512",
    "logger.progress=false",
]


def train(*args, out):
    return run_script("train.py", *TINY_TRAINING, *args, out=out)


def test_training_logs_a_validation_flight_video_to_tensorboard_at_each_evaluation(tmp_path):
    import io

    from PIL import Image, ImageSequence
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    r = train("logger.video=true", out=tmp_path)
    assert r.returncode == 0, r.stderr[-2000:]
    events = EventAccumulator(str(tmp_path / "tb"), size_guidance={"images": 0})
    events.Reload()
    videos = events.Images("eval/video")
    assert [v.step for v in videos] == [512, 1024]  # one per evaluation
    for v in videos:
        with Image.open(io.BytesIO(v.encoded_image_string)) as gif:
            images = [np.asarray(f.convert("RGB")) for f in ImageSequence.Iterator(gif)]
        assert (v.width, v.height) == (240, 180) and images[0].shape == (180, 240, 3)
        assert len(images) == 11  # the 1 s validation flight at 10 frames per second, both ends included
        assert np.abs(images[0].astype(int) - images[-1].astype(int)).mean() > 0.5  # the drone moved


def test_video_logging_is_off_by_default_and_needs_tensorboard():
    from bfc.config import compose, validate

    assert compose([]).logger.video is False  # the default run renders nothing
    with pytest.raises(ValueError) as err:
        validate(compose(["logger.video=true", "logger.tensorboard=false"]))
    assert str(err.value).startswith("logger.video must be false when logger.tensorboard=false")
