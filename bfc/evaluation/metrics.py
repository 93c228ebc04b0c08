"""Per-flight outcomes and error statistics of a batch of flights, one definition each:

- hover error: a flight's mean distance to the goal over its last 2 s (`hover_errors`); a set of
  flights reports the median over its successful flights (`hover_error`). Training's
  `eval/hover_error`, the robustness tables and bench/ all use it.
- hover tilt: the same for the tilt (`hover_tilt`; training's `eval/attitude_error`).
- position / attitude error after success: every step from the one the drone entered the box
  for its successful hold to the end of the flight (`summarize`: the protocol report).
"""

from __future__ import annotations

import torch
from tensordict import TensorDict

from bfc import keys
from bfc.evaluation.judge import judge


def tilt_degrees(quaternion: torch.Tensor) -> torch.Tensor:
    """Angle between the body z axis and the world z axis (deg): the attitude error of the protocol's
    yaw-free task (the BFC policy and, by default, the baselines keep whatever heading they have)."""
    x, y = quaternion[..., 1], quaternion[..., 2]
    return torch.rad2deg(torch.acos((1 - 2 * (x * x + y * y)).clamp(-1.0, 1.0)))


STEADY_SECONDS = 2.0  # hover errors are taken over the last 2 s of a flight


def _tail(trajectory: TensorDict, seconds: float) -> slice:
    dt = float(trajectory.get("time")[0, 0])
    return slice(-max(1, round(seconds / dt)), None)


def hover_errors(trajectory: TensorDict, seconds: float = STEADY_SECONDS) -> torch.Tensor:
    """(n,) each flight's mean distance to the goal over its last `seconds` (m)."""
    tail = _tail(trajectory, seconds)
    return (trajectory.get(keys.POSITION) - trajectory.get(keys.GOAL))[:, tail].norm(dim=-1).mean(-1)


def hover_error(trajectory: TensorDict, success: torch.Tensor) -> float | None:
    """The median over the successful flights of `hover_errors` (m); None when none succeeded."""
    if not bool(success.any()):
        return None
    return hover_errors(trajectory)[success].median().item()


def hover_tilt(trajectory: TensorDict, success: torch.Tensor) -> float | None:
    """The median over the successful flights of the mean tilt over the last 2 s (deg)."""
    if not bool(success.any()):
        return None
    tilt = tilt_degrees(trajectory.get(keys.QUATERNION)[:, _tail(trajectory, STEADY_SECONDS)]).mean(-1)
    return tilt[success].median().item()


def summarize(trajectory: TensorDict, threshold: float = 0.10, hold_seconds: float = 1.0) -> dict:
    """Success count and rate, per-start outcome and time to success, the hover error, and the mean
    and 95th percentile of position and attitude error over the flight after success."""
    ok, t_success, _ = judge(trajectory, threshold, hold_seconds)
    pos_err = (trajectory.get(keys.POSITION) - trajectory.get(keys.GOAL)).norm(dim=-1)
    att_err = tilt_degrees(trajectory.get(keys.QUATERNION))  # the task is yaw-free: heading is no error
    time = trajectory.get("time")
    after = ok.unsqueeze(-1) & (time >= torch.nan_to_num(t_success, nan=1e9).unsqueeze(-1))
    crashed = ~trajectory.get("alive")[:, -1]

    def stats(err):
        vals = err[after]
        if vals.numel() == 0:
            return {"mean": None, "p95": None}
        return {"mean": vals.mean().item(), "p95": vals.quantile(0.95).item() if vals.numel() < 2**24 else None}

    n = int(ok.numel())
    return {
        "starts": n,
        "success": int(ok.sum()),
        "fail": n - int(ok.sum()),
        "success_rate": ok.float().mean().item(),
        "crashes": int(crashed.sum()),
        "time_to_success_median": t_success[ok].median().item() if bool(ok.any()) else None,
        "hover_error_m": hover_error(trajectory, ok),
        "position_error_after_success_m": stats(pos_err),
        "attitude_error_after_success_deg": stats(att_err),
        "per_start": [
            {
                "success": bool(ok[i]),
                "time_to_success": None if not ok[i] else round(float(t_success[i]), 3),
                "crashed": bool(crashed[i]),
            }
            for i in range(n)
        ],
    }
