"""Flight figures (paper figs. 11-16): 3-D trajectories with body frames, side and top views."""

from __future__ import annotations

from pathlib import Path

import torch
from matplotlib.figure import Figure  # no pyplot: the library leaves the backend to the caller
from tensordict import TensorDict

from bfc import keys
from bfc.envs.rotations import quat_to_matrix

AXIS_COLOURS = ("red", "green", "blue")  # body x, y, z


def subplots(nrows: int = 1, ncols: int = 1, figsize=None):
    """pyplot.subplots without pyplot: a Figure that savefig renders with Agg whatever the
    process's backend, and that no global figure manager keeps alive."""
    fig = Figure(figsize=figsize)
    return fig, fig.subplots(nrows, ncols)


def _draw_frames(ax, pos, quat, every: int, length: float = 0.15):
    idx = torch.arange(0, pos.shape[0], every)
    rot = quat_to_matrix(quat[idx].double())
    for k, colour in enumerate(AXIS_COLOURS):
        d = rot[:, :, k] * length
        p = pos[idx]
        ax.quiver(p[:, 0], p[:, 1], p[:, 2], d[:, 0], d[:, 1], d[:, 2], color=colour, linewidth=0.8)


def plot_flights(
    trajectory: TensorDict, path, title: str, frame_every: int | None = 20, max_flights: int | None = None
):
    """3-D view plus side (x-z) and top (x-y) views; body frames every `frame_every` steps
    (None: only at the start)."""
    pos = trajectory.get(keys.POSITION)
    quat = trajectory.get(keys.QUATERNION)
    goal = trajectory.get(keys.GOAL)[0, -1]
    n = pos.shape[0] if max_flights is None else min(max_flights, pos.shape[0])
    fig = Figure(figsize=(13, 4.3))
    ax3 = fig.add_subplot(1, 3, 1, projection="3d")
    side = fig.add_subplot(1, 3, 2)
    top = fig.add_subplot(1, 3, 3)
    for i in range(n):
        alive = trajectory.get("alive")[i]
        colour = "tab:blue" if bool(alive[-1]) else "tab:gray"
        p = pos[i]
        ax3.plot(p[:, 0], p[:, 1], p[:, 2], color=colour, linewidth=0.7, alpha=0.8)
        side.plot(p[:, 0], p[:, 2], color=colour, linewidth=0.7, alpha=0.8)
        top.plot(p[:, 0], p[:, 1], color=colour, linewidth=0.7, alpha=0.8)
        _draw_frames(ax3, p, quat[i], frame_every if frame_every else 10**9)
    for ax in (side, top):
        ax.set_aspect("equal", adjustable="datalim")
        ax.grid(alpha=0.3)
    ax3.scatter(*goal.tolist(), color="black", marker="*", s=80)
    side.scatter(goal[0], goal[2], color="black", marker="*", s=80, zorder=5)
    top.scatter(goal[0], goal[1], color="black", marker="*", s=80, zorder=5)
    ax3.set_xlabel("x (m)")
    ax3.set_ylabel("y (m)")
    ax3.set_zlabel("z (m)")
    side.set_xlabel("x (m)")
    side.set_ylabel("z (m)")
    side.set_title("side view")
    top.set_xlabel("x (m)")
    top.set_ylabel("y (m)")
    top.set_title("top view")
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def plot_errors(trajectory: TensorDict, path, title: str = "position and attitude error"):
    """Position and attitude error against time, median and 10-90% band over flights (fig. 17)."""
    from bfc.evaluation.metrics import tilt_degrees

    t = trajectory.get("time")[0]
    pos_err = (trajectory.get(keys.POSITION) - trajectory.get(keys.GOAL)).norm(dim=-1)
    att = tilt_degrees(trajectory.get(keys.QUATERNION))
    fig, axes = subplots(1, 2, figsize=(10, 3.4))
    for ax, err, label in ((axes[0], pos_err, "position error (m)"), (axes[1], att, "attitude error: tilt (deg)")):
        q = torch.quantile(err, torch.tensor([0.1, 0.5, 0.9]), dim=0)
        ax.fill_between(t, q[0], q[2], alpha=0.3, label="10-90%")
        ax.plot(t, q[1], label="median")
        ax.set_xlabel("time (s)")
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.grid(alpha=0.3)
        ax.legend()
    fig.suptitle(title)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def flight_figures(trajectory: TensorDict, out) -> list[Path]:
    """The standard set: one flight, ten flights (frames every 20 steps), all flights (frames at
    the start only), and the error curves."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "flight_1.png", out / "flights_10.png", out / "flights_all.png", out / "errors.png"]
    plot_flights(trajectory[:1], paths[0], "one flight (body frame every 20 steps)")
    plot_flights(trajectory[:10], paths[1], "ten flights (body frame every 20 steps)")
    plot_flights(trajectory, paths[2], f"{trajectory.shape[0]} flights (body frame at the start)", frame_every=None)
    plot_errors(trajectory, paths[3])
    return paths
