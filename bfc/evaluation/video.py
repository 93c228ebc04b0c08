"""Videos of flights, rendered by MuJoCo's own offscreen renderer (`evaluate.py video=true`).

Why it is built this way:
- A flight already records every step's ground-truth pose (position and quaternion: the drone's
  qpos), so a video needs no second simulation: each frame sets one MjData's qpos from the record,
  runs mj_forward and renders. The frames are drawn after the evaluation, so its numbers are
  written whatever the renderer does.
- The physics model has no visual geometry but its translucent collision box; the render model is
  the same asset with visual-only geoms (arms, rotors, the front rotor red) and a lit floor. The
  goal, its success box and the trace are user geoms added to each frame's scene (mjvScene), never
  part of a model; time, motor speeds and the flight's state are drawn onto the image with Pillow
  (already installed: matplotlib needs it).
- MP4 through PyAV (the `video` extra: FFmpeg's libraries in its wheel, in process); the GIF through
  Pillow, at no more than 15 frames per second.
- MuJoCo picks its OpenGL backend when first imported (MUJOCO_GL): `bfc.headless_gl`, imported
  first by the entry points, makes it EGL on a Linux machine without a display.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path

import numpy as np
import torch

from bfc import keys
from bfc.envs.params import HUMMINGBIRD, AirframeParams
from bfc.envs.rotations import euler_to_quat
from bfc.evaluation.judge import flight_dt

CAMERAS = ("chase", "fixed")  # chase: follows the drone; fixed: looks at the goal from 7 m
PICKS = ("tilted", "first")  # tilted: the starts released most tilted; first: the first starts
GIF_MAX_FPS = 15.0
INSTALL_GL = (
    "use MUJOCO_GL=egl (apt-get install -y libegl1 libgl1-mesa-dri) or MUJOCO_GL=osmesa (apt-get install -y libosmesa6)"
)


class RendererUnavailable(RuntimeError):
    """No OpenGL context could be made: the message says what to install."""


def writer_missing() -> str | None:
    """None when the MP4 writer (PyAV, the `video` extra) imports, else the one line to install it."""
    try:
        import av  # noqa: F401
    except ImportError:
        return "video=true needs the video extra (PyAV): pip install -e '.[video]'"
    return None


def check_options(fps: float, width: int, height: int, starts: int, camera: str, pick: str, seconds) -> None:
    """The video keys of evaluate.py: one ValueError naming the first bad one."""
    if camera not in CAMERAS:
        raise ValueError(f"video_camera must be one of {', '.join(CAMERAS)}, got {camera!r}")
    if pick not in PICKS:
        raise ValueError(f"video_pick must be one of {', '.join(PICKS)}, got {pick!r}")
    if not 1 <= fps <= 120:
        raise ValueError(f"video_fps must be in [1, 120], got {fps}")
    for name, v in (("video_width", width), ("video_height", height)):
        if not (16 <= v <= 4096 and v % 2 == 0):
            raise ValueError(f"{name} must be an even number of pixels in [16, 4096] (H.264), got {v}")
    if starts < 1:
        raise ValueError(f"video_starts must be >= 1, got {starts}")
    if seconds is not None and seconds <= 0:
        raise ValueError(f"video_seconds must be > 0 or null (the whole flight), got {seconds}")


def start_tilt_degrees(starts: torch.Tensor) -> torch.Tensor:
    """(n,) the angle between the body's z axis and the vertical at release, from (n, 12) starts."""
    q = euler_to_quat(starts[:, 3:6].double())
    cos = 1 - 2 * (q[:, 1] ** 2 + q[:, 2] ** 2)
    return torch.rad2deg(torch.arccos(cos.clamp(-1, 1)))


def pick_starts(starts: torch.Tensor, count: int, how: str) -> list[int]:
    """Indices of the starts to film: the `count` first, or the `count` released most tilted."""
    count = min(count, starts.shape[0])
    if how == "first":
        return list(range(count))
    return start_tilt_degrees(starts).argsort(descending=True, stable=True)[:count].tolist()


@dataclass
class Clip:
    """One flight to film, the release first: (T + 1) poses at the control step `dt`."""

    title: str
    dt: float
    position: np.ndarray  # (T + 1, 3) world, m
    quaternion: np.ndarray  # (T + 1, 4) w, x, y, z
    motors: np.ndarray  # (T + 1, 4) rad/s
    goal: np.ndarray  # (T + 1, 3)
    alive: np.ndarray  # (T + 1,) bool
    threshold: float  # the success box's half size, m
    airframe: AirframeParams | None = None  # the drone drawn (the Hummingbird when None)


def clips_from_flights(
    flights, starts: torch.Tensor, indices, threshold: float, label: str = "", airframe: AirframeParams | None = None
) -> list[Clip]:
    """The chosen flights of a `fly` result (n, T) as clips; `starts` (n, 12) are their releases;
    `airframe` the drone they flew (drawn to its size)."""
    dt = flight_dt(flights)
    tilt = start_tilt_degrees(starts)
    out = []
    for i in indices:
        s = starts[i].double()
        q0 = euler_to_quat(s[3:6].unsqueeze(0))[0]

        def column(key, first, i=i):
            rest = flights.get(key)[i].double()
            return torch.cat([torch.as_tensor(first, dtype=torch.float64).reshape(1, -1), rest.reshape(len(rest), -1)])

        goal = flights.get(keys.GOAL)[i]
        out.append(
            Clip(
                title=f"{label + ' ' if label else ''}start {i}, released {tilt[i].item():.0f} deg tilted",
                dt=dt,
                position=column(keys.POSITION, s[:3]).numpy(),
                quaternion=column(keys.QUATERNION, q0).numpy(),
                motors=column(keys.MOTOR_SPEEDS, torch.zeros(4)).numpy(),
                goal=column(keys.GOAL, goal[0]).numpy(),
                alive=column("alive", True).bool().reshape(-1).numpy(),
                threshold=float(threshold),
                airframe=airframe,
            )
        )
    return out


def slug(name: str) -> str:
    """A file-name part for a suite row: 'mass +30%' -> 'mass_plus30'."""
    name = name.lower().replace("+", "plus").replace("-", "minus")
    return re.sub(r"[^a-z0-9]+", "_", name).strip("_")


def render_model(width: int, height: int, airframe: AirframeParams | None = None):
    """The airframe's model with visual-only geoms and a lit floor (the physics model is untouched)."""
    import mujoco

    from bfc.envs.quadrotor import BODY, airframe_spec

    air = airframe or HUMMINGBIRD
    spec = airframe_spec(air)
    spec.add_texture(
        name="grid",
        type=mujoco.mjtTexture.mjTEXTURE_2D,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_CHECKER,
        rgb1=[0.8, 0.81, 0.83],
        rgb2=[0.74, 0.75, 0.78],
        width=64,
        height=64,
    )
    spec.add_texture(
        name="sky",
        type=mujoco.mjtTexture.mjTEXTURE_SKYBOX,
        builtin=mujoco.mjtBuiltin.mjBUILTIN_FLAT,
        rgb1=[0.88, 0.92, 0.97],
        rgb2=[0.88, 0.92, 0.97],
        width=16,
        height=16,
    )
    floor = spec.add_material(name="grid", texrepeat=[20, 20])
    floor.textures[mujoco.mjtTextureRole.mjTEXROLE_RGB] = "grid"
    spec.geom("floor").material = "grid"
    spec.geom("hull").group = 3  # the collision box: not drawn
    spec.worldbody.add_light(pos=[0, 0, 8], dir=[0, 0, -1], diffuse=[0.6, 0.6, 0.6], castshadow=False)
    spec.visual.headlight.ambient = [0.45, 0.45, 0.45]
    spec.visual.headlight.diffuse = [0.4, 0.4, 0.4]
    spec.visual.rgba.haze = [0.93, 0.95, 0.98, 1]
    spec.stat.extent = 6.0  # fog/haze scale: the flight box, not the tiny drone
    body = spec.body(BODY)
    visual = {"contype": 0, "conaffinity": 0, "group": 1, "mass": 0}
    k = air.arm_length / 0.17  # the drawing is the Hummingbird's, scaled to the arm
    body.add_geom(
        type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.045 * k, 0.045 * k, 0.02 * k], rgba=[0.15, 0.15, 0.18, 1], **visual
    )
    for tip in air.rotor_positions:
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CAPSULE,
            fromto=[0, 0, 0, *tip],
            size=[0.009 * k, 0, 0],
            rgba=[0.2, 0.2, 0.22, 1],
            **visual,
        )
        front = tip[0] > 1e-9  # the rotors ahead of the centre (+x): red, so the heading shows
        rgba = [0.85, 0.15, 0.1, 0.75] if front else [0.1, 0.35, 0.8, 0.6]
        body.add_geom(
            type=mujoco.mjtGeom.mjGEOM_CYLINDER, pos=list(tip), size=[0.1 * k, 0.004 * k, 0], rgba=rgba, **visual
        )
    model = spec.compile()
    model.vis.global_.offwidth, model.vis.global_.offheight = max(width, 640), max(height, 480)
    return model


def _open_renderer(model, width: int, height: int):
    import os
    import warnings

    import mujoco

    from bfc import headless_gl

    backend = os.environ.get("MUJOCO_GL") or "glfw (MUJOCO_GL unset)"
    problem = headless_gl.PROBLEM  # a MUJOCO_GL that bfc.headless_gl turned off
    if problem is None:
        try:
            with warnings.catch_warnings():  # GLFW warns before it fails: the one line below says it all
                warnings.simplefilter("ignore")
                renderer = mujoco.Renderer(model, height, width, max_geom=2000)
                renderer.render()  # a context that cannot draw fails here, not midway through a video
            return renderer
        except Exception as err:  # the backends fail with ImportError, AttributeError, FatalError...
            first = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
            problem = f"MUJOCO_GL={backend} failed ({first[:90]})"
            if not os.environ.get("DISPLAY") and backend.split()[0] in ("glfw", "glx", "", "enable", "1", "on"):
                problem = f"MUJOCO_GL={backend} needs a display (DISPLAY is unset)"
    raise RendererUnavailable(f"video=true needs an OpenGL renderer; {problem}: {INSTALL_GL}")


def _add_geom(scene, kind, size, pos, rgba, mat=None) -> None:
    import mujoco

    if scene.ngeom >= scene.maxgeom:
        return
    g = scene.geoms[scene.ngeom]
    mat = np.eye(3).reshape(-1) if mat is None else mat
    mujoco.mjv_initGeom(g, kind, np.asarray(size, float), np.asarray(pos, float), mat, np.asarray(rgba, np.float32))
    scene.ngeom += 1


def _add_line(scene, a, b, rgba, width: float) -> None:
    import mujoco

    if scene.ngeom >= scene.maxgeom:
        return
    g = scene.geoms[scene.ngeom]
    mujoco.mjv_initGeom(g, mujoco.mjtGeom.mjGEOM_LINE, np.zeros(3), np.zeros(3), np.eye(3).reshape(-1), rgba)
    mujoco.mjv_connector(g, mujoco.mjtGeom.mjGEOM_LINE, width, np.asarray(a, float), np.asarray(b, float))
    scene.ngeom += 1


TRACE_SEGMENTS = 200  # at most this many line segments trace a flight (the record is subsampled)


def _decorate(scene, clip: Clip, k: int, line_width: float) -> None:
    """The goal (a green ball), its success box, the start (grey) and the trace up to record step k."""
    import mujoco

    goal = clip.goal[k]
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.035, 0, 0], goal, [0.1, 0.75, 0.2, 0.9])
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_BOX, [clip.threshold] * 3, goal, [0.1, 0.75, 0.2, 0.18])
    _add_geom(scene, mujoco.mjtGeom.mjGEOM_SPHERE, [0.025, 0, 0], clip.position[0], [0.4, 0.4, 0.4, 0.8])
    stride = max(1, math.ceil(len(clip.position) / TRACE_SEGMENTS))
    points = list(range(0, k, stride)) + [k]
    rgba = np.array([0.95, 0.5, 0.05, 1], np.float32)
    for a, b in zip(points[:-1], points[1:], strict=True):
        _add_line(scene, clip.position[a], clip.position[b], rgba, line_width)


class _Camera:
    """chase: looks at the drone (smoothed over 0.3 s) from further away the further it is from the
    goal, so both stay in view; fixed: looks at the goal from 7 m."""

    def __init__(self, kind: str, clip: Clip, fps: float):
        import mujoco

        self.kind, self.cam = kind, mujoco.MjvCamera()
        self.cam.type = mujoco.mjtCamera.mjCAMERA_FREE
        self.cam.azimuth, self.cam.elevation = 135.0, -18.0
        self.alpha = 1.0 - math.exp(-1.0 / (0.3 * fps))
        self.lookat = clip.position[0].copy()
        self.distance = self._distance(clip, 0)
        if kind == "fixed":
            self.cam.lookat[:] = clip.goal[0] - np.array([0, 0, 0.3])
            self.cam.distance, self.cam.elevation = 7.0, -20.0

    @staticmethod
    def _distance(clip: Clip, k: int) -> float:
        """1.6 m from a Hummingbird at the goal (closer to a smaller airframe), plus 0.9 m per
        metre from the goal."""
        size = (clip.airframe or HUMMINGBIRD).arm_length / HUMMINGBIRD.arm_length
        return 1.6 * min(max(size, 0.3), 2.0) + 0.9 * float(np.linalg.norm(clip.position[k] - clip.goal[k]))

    def at(self, clip: Clip, k: int):
        if self.kind == "chase":
            self.lookat += self.alpha * (clip.position[k] - self.lookat)
            self.distance += self.alpha * (self._distance(clip, k) - self.distance)
            self.cam.lookat[:] = self.lookat
            self.cam.distance = self.distance
        return self.cam


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.load_default(size=size)
    except TypeError:  # Pillow < 10.1: the fixed bitmap font
        return ImageFont.load_default()


def _overlay(image: np.ndarray, clip: Clip, k: int, t: float, font) -> np.ndarray:
    """Time, the flight's title and state, and the four motor speeds, drawn onto the frame."""
    from PIL import Image, ImageDraw

    img = Image.fromarray(image)
    draw = ImageDraw.Draw(img)
    h = img.height
    pad = max(3, h // 80)
    inside = bool(np.all(np.abs(clip.position[k] - clip.goal[k]) <= clip.threshold))
    state, color = (
        ("crashed", (200, 30, 20))
        if not clip.alive[k]
        else (("in the goal box", (20, 130, 40)) if inside else ("flying", (30, 30, 30)))
    )
    motors = " ".join(f"{w:4.0f}" for w in clip.motors[k])
    lines = [(clip.title, (30, 30, 30)), (f"t = {t:5.2f} s   {state}", color), (f"motors {motors} rad/s", (30, 30, 30))]
    y = pad
    for text, fill in lines[:2]:
        draw.text((pad, y), text, font=font, fill=fill, stroke_width=1, stroke_fill=(255, 255, 255))
        y += int(font.size * 1.25) if hasattr(font, "size") else 12
    text, fill = lines[2]
    bottom = h - pad - (int(font.size * 1.2) if hasattr(font, "size") else 12)
    draw.text((pad, bottom), text, font=font, fill=fill, stroke_width=1, stroke_fill=(255, 255, 255))
    return np.asarray(img)


def clip_frames(clip: Clip, fps: float, seconds: float | None = None) -> int:
    """The frames a clip takes: one every 1/fps s from the release to `seconds` (or its end), both included."""
    length = (len(clip.position) - 1) * clip.dt
    span = length if seconds is None else min(seconds, length)
    return int(math.floor(span * fps + 1e-6)) + 1


def frames(clips, fps: float, width: int, height: int, camera: str = "chase", seconds: float | None = None):
    """Yield every frame (height, width, 3) uint8 of the clips, one after another.

    Raises RendererUnavailable (before the first frame) when no OpenGL context can be made."""
    import mujoco

    model = render_model(width, height, clips[0].airframe if clips else None)
    data = mujoco.MjData(model)
    renderer = _open_renderer(model, width, height)
    font = _font(max(9, height // 20))
    line_width = max(1.5, height / 200)
    try:
        for clip in clips:
            cam = _Camera(camera, clip, fps)
            last = len(clip.position) - 1
            for f in range(clip_frames(clip, fps, seconds)):
                t = f / fps
                k = min(last, round(t / clip.dt))
                data.qpos[:3], data.qpos[3:7] = clip.position[k], clip.quaternion[k]
                mujoco.mj_forward(model, data)
                renderer.update_scene(data, camera=cam.at(clip, k))
                _decorate(renderer.scene, clip, k, line_width)
                yield _overlay(renderer.render(), clip, k, t, font)
    finally:
        renderer.close()


def write_video(clips, stem: Path, fps: float, width: int, height: int, camera: str = "chase", seconds=None):
    """Render the clips into `stem`.mp4 (H.264, every frame) and `stem`.gif (at most 15 fps).

    Returns (the paths written, the number of MP4 frames). Raises RendererUnavailable with one line
    saying what to install when no OpenGL context can be made (nothing is written then)."""
    import av
    from PIL import Image

    stem = Path(stem)
    gif_every = max(1, math.ceil(fps / GIF_MAX_FPS))
    mp4, gif = stem.with_suffix(".mp4"), stem.with_suffix(".gif")
    it = frames(clips, fps, width, height, camera, seconds)
    first = next(it)  # opens the renderer: RendererUnavailable before any file is created
    gif_frames, n = [], 0
    with av.open(str(mp4), mode="w") as container:
        stream = container.add_stream("libx264", rate=Fraction(fps).limit_denominator(1001))
        stream.width, stream.height, stream.pix_fmt = width, height, "yuv420p"
        stream.options = {"crf": "23", "preset": "veryfast"}
        for image in _chain(first, it):
            if n % gif_every == 0:
                gif_frames.append(Image.fromarray(image).quantize(colors=96, method=Image.Quantize.MEDIANCUT))
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            for packet in stream.encode(frame):
                container.mux(packet)
            n += 1
        for packet in stream.encode():
            container.mux(packet)
    _save_gif(gif_frames, gif, fps / gif_every)
    return [mp4, gif], n


def _save_gif(images, target, fps: float) -> None:
    """Pillow images (quantized) as an endlessly looping GIF, to a path or a binary file."""
    images[0].save(
        target, format="GIF", save_all=True, append_images=images[1:], duration=round(1000 / fps), loop=0, optimize=True
    )


def check_renderer() -> None:
    """Raise RendererUnavailable (one line: what to install) unless an OpenGL context can be made."""
    model = render_model(32, 32)
    _open_renderer(model, 32, 32).close()


def tensorboard_video(tag: str, clip: Clip, fps: float = 10.0, width: int = 240, height: int = 180, seconds=4.0):
    """One clip as a TensorBoard summary: an animated GIF in an image summary, what torch's
    SummaryWriter.add_video writes, without its moviepy dependency (TensorBoard's Images tab plays it)."""
    import io

    from PIL import Image
    from tensorboard.compat.proto.summary_pb2 import Summary

    fps = min(fps, GIF_MAX_FPS)
    images = [
        Image.fromarray(f).quantize(colors=96, method=Image.Quantize.MEDIANCUT)
        for f in frames([clip], fps, width, height, "chase", seconds)
    ]
    buffer = io.BytesIO()
    _save_gif(images, buffer, fps)
    image = Summary.Image(height=height, width=width, colorspace=3, encoded_image_string=buffer.getvalue())
    return Summary(value=[Summary.Value(tag=tag, image=image)])


def _chain(first, rest):
    yield first
    yield from rest
