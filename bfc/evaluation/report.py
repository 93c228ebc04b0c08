"""The paper's evaluation suite as one Markdown report with PNG figures.

What it produces for one policy (seconds each, batched): the protocol table, accuracy over a 10 s
hover (fig. 17), robustness to odometry noise added at evaluation time (fig. 18), a sparse and a
dense waypoint course (fig. 22) and the flight figures (figs. 11-16). Given a directory of training
runs (a `-m` sweep), it adds Table 2 (each run's final policy flown on the test starts of the
protocol, take-off and any-attitude sets: mean, spread and each seed, per ablation variant) and the
learning curves with a band over seeds (figs. 8-10) read from the runs' summaries.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import torch
from tensordict import TensorDict

from bfc.config import TestProtocolConfig
from bfc.envs import GOAL
from bfc.envs.rotations import euler_to_quat
from bfc.evaluation.flying import fly
from bfc.evaluation.metrics import summarize, tilt_degrees
from bfc.evaluation.plots import flight_figures, plot_flights, subplots
from bfc.evaluation.protocol import protocol_starts

NOISE_CONDITIONS = [
    ("none", {"kind": "none"}),
    *[(f"gaussian {s} all", {"kind": "gaussian", "std": s, "elements": "all"}) for s in (0.05, 0.1, 0.2)],
    ("ou 0.05 all", {"kind": "ou", "std": 0.05, "theta": 1.0, "elements": "all"}),
    *[(f"gaussian {s} position", {"kind": "gaussian", "std": s, "elements": "position"}) for s in (0.05, 0.1, 0.2)],
    ("ou 0.05 position", {"kind": "ou", "std": 0.05, "theta": 1.0, "elements": "position"}),
]
SPARSE_COURSE = [(0.0, (1.0, 1.0, 1.5)), (5.0, (-1.0, 1.0, 2.0)), (10.0, (-1.0, -1.0, 1.5)), (15.0, (1.0, -1.0, 1.0))]


def dense_course(points: int = 24, seconds_each: float = 0.75, radius: float = 1.0) -> list:
    """A circle of `points` waypoints, one every `seconds_each` (a smooth path)."""
    return [
        (
            i * seconds_each,
            (
                radius * math.cos(2 * math.pi * i / points),
                radius * math.sin(2 * math.pi * i / points),
                1.5 + 0.3 * math.sin(4 * math.pi * i / points),
            ),
        )
        for i in range(points)
    ]


def _fmt(v, digits=3):
    return "n/a" if v is None else f"{v:.{digits}f}"


def policy_sections(controller, out: Path, protocol: TestProtocolConfig) -> tuple[list[str], TensorDict]:
    """The protocol, accuracy, noise and waypoint sections, and the protocol flights (reused by the
    controller comparison)."""
    p = protocol
    num_starts, seed = p.num_starts, p.seed
    starts = protocol_starts(num_starts, seed)
    lines = []
    flights = fly(controller, starts, seconds=p.seconds, seed=seed)
    s = summarize(flights, p.threshold, p.hold_seconds)
    (out / "protocol.json").write_text(json.dumps(s, indent=1))
    flight_figures(flights, out)
    lines += [
        "## Protocol (paper sec. 7.1)",
        f"{num_starts} starts from `protocol_starts({num_starts}, seed={seed})`, {p.seconds:g} s, "
        f"success = within {p.threshold:g} m on every axis for {p.hold_seconds:g} s.",
        "",
        "| success | fail | crashes | median time to success (s) | position error after success, mean / p95 (m) "
        "| tilt after success, mean / p95 (deg) |",
        "|---|---|---|---|---|---|",
        f"| {s['success']} | {s['fail']} | {s['crashes']} | {_fmt(s['time_to_success_median'], 2)} "
        f"| {_fmt(s['position_error_after_success_m']['mean'])} / {_fmt(s['position_error_after_success_m']['p95'])} "
        f"| {_fmt(s['attitude_error_after_success_deg']['mean'], 2)} / "
        f"{_fmt(s['attitude_error_after_success_deg']['p95'], 2)} |",
        "",
        "Paper's BFC: 90.5 / 9.5 (Table 2).",
        "",
        "![one flight](flight_1.png)",
        "",
        "![ten flights](flights_10.png)",
        "",
        f"![{num_starts} flights](flights_all.png)",
        "",
        "## Accuracy (fig. 17)",
        "Position and attitude error against time over the same flights (median and 10-90% band).",
        "",
        "![errors](errors.png)",
        "",
    ]
    rows = []
    for name, noise in NOISE_CONDITIONS:
        nf = fly(controller, starts, seconds=p.seconds, noise=noise, seed=seed)
        ns = summarize(nf, p.threshold, p.hold_seconds)
        rows.append((name, ns))
    _noise_figure(rows, out / "noise.png")
    lines += [
        "## Odometry noise at evaluation time (fig. 18)",
        "The policy was trained without noise; noise corrupts only what it sees (success is judged on the truth).",
        "",
        "| noise | success | crashes | position error after success (m) | tilt after success (deg) |",
        "|---|---|---|---|---|",
        *[
            f"| {name} | {ns['success']}/{ns['starts']} | {ns['crashes']} "
            f"| {_fmt(ns['position_error_after_success_m']['mean'])} "
            f"| {_fmt(ns['attitude_error_after_success_deg']['mean'], 2)} |"
            for name, ns in rows
        ],
        "",
        "![noise](noise.png)",
        "",
    ]
    level = torch.zeros(1, 12)
    level[0, :3] = torch.tensor(GOAL)  # level, at rest, at the hover goal
    for label, course, seconds, fname in (
        ("sparse (4 waypoints, 5 s each)", SPARSE_COURSE, 20.0, "waypoints_sparse.png"),
        ("dense (a circle of 24 waypoints, 0.75 s each)", dense_course(), 18.0, "waypoints_dense.png"),
    ):
        wf = fly(controller, level, seconds=seconds, goal=course, seed=seed)
        plot_flights(wf, out / fname, f"waypoints: {label}", frame_every=25)
        lines += [f"## Waypoints (fig. 22): {label}", "", f"![{label}]({fname})", ""]
    return lines, flights


TILT_BINS = (0, 15, 30, 45, 60, 75, 90)  # degrees of initial tilt (roll and pitch up to 60 give up to 75.5)


def start_tilt_degrees(starts: torch.Tensor) -> torch.Tensor:
    """(n,) angle between the body z axis and the vertical at the start (deg)."""
    return tilt_degrees(euler_to_quat(starts[:, 3:6].double()))


def controller_sections(
    controllers: dict, out: Path, protocol: TestProtocolConfig, flown: dict | None = None
) -> list[str]:
    """BFC against the classical baselines on the same starts (paper figs. 19-21): success, success
    by initial tilt, time to success, errors after success and compute time per control step."""
    p = protocol
    num_starts, seed = p.num_starts, p.seed
    starts = protocol_starts(num_starts, seed)
    tilt = start_tilt_degrees(starts)
    bins = [(lo, hi, (tilt >= lo) & (tilt < hi)) for lo, hi in zip(TILT_BINS[:-1], TILT_BINS[1:], strict=True)]
    bins = [b for b in bins if bool(b[2].any())]
    table, by_tilt = [], {}
    for label, controller in controllers.items():
        flights = (flown or {}).get(label)  # flights already flown on these starts, by label
        if flights is None:
            flights = fly(controller, starts, seconds=p.seconds, seed=seed)
        s = summarize(flights, p.threshold, p.hold_seconds)
        ok = torch.tensor([r["success"] for r in s["per_start"]])
        by_tilt[label] = [ok[mask].float().mean().item() for _, _, mask in bins]
        step_ms = 1e3 * flights.get("controller_seconds")[0, 1:].mean().item()  # the first call sets up
        table.append(
            f"| {label} | {s['success']}/{s['starts']} | {s['crashes']} | {_fmt(s['time_to_success_median'], 2)} "
            f"| {_fmt(s['position_error_after_success_m']['mean'])} "
            f"| {_fmt(s['attitude_error_after_success_deg']['mean'], 2)} "
            f"| {step_ms:.2f} | {1e3 * step_ms / num_starts:.1f} |"
        )
        plot_flights(flights[:10], out / f"flights_{label}.png", f"{label}: ten protocol flights", frame_every=25)
    _tilt_figure(bins, by_tilt, out / "controllers_tilt.png")
    names = list(controllers)
    return [
        "## Controllers on the same starts (figs. 19-21)",
        "Every controller flies the same protocol starts through the same env at its own control rate; "
        "compute is the wall-clock of one call for the whole batch, and per env.",
        "",
        "| controller | success | crashes | median time to success (s) | position error after success (m) "
        "| tilt after success (deg) | compute per step, batch (ms) | per env (us) |",
        "|---|---|---|---|---|---|---|---|",
        *table,
        "",
        "Success by initial tilt (the angle between the body's z axis and the vertical at release):",
        "",
        "| initial tilt (deg) | starts | " + " | ".join(names) + " |",
        "|---|---|" + "---|" * len(names),
        *[
            f"| {lo}-{hi} | {int(mask.sum())} | " + " | ".join(f"{by_tilt[n][i]:.2f}" for n in names) + " |"
            for i, (lo, hi, mask) in enumerate(bins)
        ],
        "",
        "![success by initial tilt](controllers_tilt.png)",
        "",
        *[f"![{n}](flights_{n}.png)\n" for n in names],
    ]


def _tilt_figure(bins, by_tilt: dict, path) -> None:
    fig, ax = subplots(figsize=(8, 3.6))
    width = 0.8 / max(1, len(by_tilt))
    for k, (label, rates) in enumerate(by_tilt.items()):
        ax.bar([i + k * width for i in range(len(bins))], rates, width, label=label)
    ax.set_xticks([i + 0.4 - width / 2 for i in range(len(bins))], [f"{lo}-{hi}" for lo, hi, _ in bins])
    ax.set_xlabel("initial tilt (deg)")
    ax.set_ylabel("success rate")
    ax.set_ylim(0, 1.05)
    ax.grid(alpha=0.3, axis="y")
    ax.legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def _noise_figure(rows, path):
    names = [r[0] for r in rows]
    rate = [r[1]["success_rate"] for r in rows]
    err = [r[1]["position_error_after_success_m"]["mean"] or float("nan") for r in rows]
    fig, axes = subplots(1, 2, figsize=(11, 3.6))
    axes[0].barh(names, rate, color="tab:blue")
    axes[0].set_xlabel("success rate")
    axes[0].set_xlim(0, 1)
    axes[1].barh(names, err, color="tab:orange")
    axes[1].set_xlabel("position error after success (m)")
    for ax in axes:
        ax.invert_yaxis()
        ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


KEPT_SCALARS = "scalars.json"  # {tag: [[frames, value], ...]}: a kept run's curves without its events


def tb_scalars(run_dir: Path, tag: str) -> tuple[torch.Tensor, torch.Tensor]:
    """(frames, values) of one scalar tag from a run's TensorBoard events (or, for a run kept in
    the repository without them, its KEPT_SCALARS file)."""
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    kept = run_dir / KEPT_SCALARS
    if kept.is_file():
        pairs = json.loads(kept.read_text()).get(tag, [])
        values = torch.tensor(pairs, dtype=torch.float64).reshape(-1, 2)
        return values[:, 0], values[:, 1].float()
    if not (run_dir / "tb").is_dir():  # a run with logger.tensorboard=false
        return torch.zeros(0), torch.zeros(0)
    acc = EventAccumulator(str(run_dir / "tb"), size_guidance={"scalars": 0})
    acc.Reload()
    if tag not in acc.Tags().get("scalars", []):
        return torch.zeros(0), torch.zeros(0)
    events = acc.Scalars(tag)
    return torch.tensor([e.step for e in events], dtype=torch.float64), torch.tensor([e.value for e in events])


def _plot_band(ax, x: torch.Tensor, curves: list[torch.Tensor], label: str) -> None:
    """Mean over seeds with a min-max band (curves cut to the shortest)."""
    k = min(len(c) for c in curves)
    if k == 0:
        return
    stack = torch.stack([c[:k] for c in curves])
    ax.plot(x[:k], stack.nanmean(0), label=label)
    if len(curves) > 1:
        ax.fill_between(x[:k], stack.min(0).values, stack.max(0).values, alpha=0.15)


PAPER_ORDER = ("ppo", "jd", "css", "tdts", "jd_css", "jd_tdts", "css_tdts", "jd_css_tdts")
TABLE2_STARTS = {"protocol": "protocol", "ground": "take-off (ground)", "any": "any attitude"}


def run_algo_and_variant(cfg: dict) -> tuple[str, str]:
    """(algo.name, variant) of a run from its saved config.yaml (PPO when it names none)."""
    return (cfg.get("algo") or {}).get("name", "ppo"), cfg.get("variant") or "?"


def read_runs(*runs_dirs: Path) -> dict[str, list[dict]]:
    """{row label: [run, ...]} for every run (`summary.json` + `config.yaml`) below the `runs_dirs`;
    PPO rows keep the variant's name, other algorithms are prefixed with theirs; paper order."""
    import yaml

    by_variant: dict[str, list[dict]] = {}
    for summary_path in sorted(p for d in runs_dirs for p in Path(d).rglob("summary.json")):
        cfg = yaml.safe_load((summary_path.parent / "config.yaml").read_text())
        algo, variant = run_algo_and_variant(cfg)
        label = variant if algo == "ppo" else f"{algo} {variant}"
        by_variant.setdefault(label, []).append(
            {
                "dir": summary_path.parent,
                "seed": cfg["seed"],
                "frames": cfg["collector"]["total_frames"],
                "schedule_frames": cfg["collector"]["total_frames"],  # "frames": as far as it went (summary)
                **json.loads(summary_path.read_text()),
            }
        )

    def order(label: str):
        algo, _, variant = label.rpartition(" ")
        return (algo, PAPER_ORDER.index(variant) if variant in PAPER_ORDER else len(PAPER_ORDER), variant)

    return {label: sorted(by_variant[label], key=lambda r: r["seed"]) for label in sorted(by_variant, key=order)}


def fly_final_policies(by_variant: dict, protocol: TestProtocolConfig) -> None:
    """Each run's `policy_last.pt` (the final policy: never chosen on any starts) on the test
    starts of every set in TABLE2_STARTS: run["test"] = {set: success rate}."""
    from bfc.evaluation.flying import airframe_of
    from bfc.evaluation.suites import score, start_set

    p = protocol
    for runs in by_variant.values():
        for run in runs:
            policy = run["dir"] / "policy_last.pt"
            run["test"] = {}
            for name in TABLE2_STARTS if policy.is_file() else ():
                starts = start_set(name, p.num_starts, p.seed, airframe_of(policy))
                flights = fly(policy, starts, seconds=p.seconds, seed=p.seed)
                run["test"][name] = score(flights, p.threshold, p.hold_seconds)["success_rate"]


def mean_spread(rates: list) -> str:
    """Percent: mean +- sample standard deviation over seeds, then each seed's value (None: a run
    without that figure, shown as n/a and left out of the mean)."""
    known = [r for r in rates if r is not None]
    if not known:
        return "n/a"
    pct = torch.tensor(known, dtype=torch.float64) * 100
    sd = pct.std().item() if len(known) > 1 else 0.0
    each = ", ".join("n/a" if r is None else f"{100 * r:.0f}" for r in rates)
    return f"{pct.mean().item():.1f} +- {sd:.1f} ({each})"


def _first_reached(run: dict) -> str:
    reach = run.get("first_reached_0.905")
    return "never" if reach is None else f"{reach['frames'] / 1e6:.1f}M"


def table2(by_variant: dict, protocol: TestProtocolConfig) -> list[str]:
    """Table 2: the final policies on the test starts (mean, spread and seeds), the validation
    evaluations the runs made, and when each seed first reached the paper's 0.905."""
    sets = [TABLE2_STARTS[name] for name in TABLE2_STARTS]
    lines = [
        "| variant | seeds | frames each | "
        + " | ".join(f"{s}, final policy" for s in sets)
        + " | validation, last evaluation | validation, best evaluation | 0.905 first reached (validation) |",
        "|---|---|---|" + "---|" * (len(sets) + 3),
    ]
    for variant, runs in by_variant.items():
        test = [mean_spread([r.get("test", {}).get(name) for r in runs]) for name in TABLE2_STARTS]
        final = mean_spread([r["final_success_rate"] for r in runs])
        best = mean_spread([r["best_success_rate"] if r["history"] else None for r in runs])
        reached = ", ".join(_first_reached(r) for r in runs)
        cells = [variant, str(len(runs)), f"{runs[0]['frames']:,}", *test, final, best, reached]
        lines.append("| " + " | ".join(cells) + " |")
    p = protocol
    lines += [
        "",
        f"Success in percent: mean +- sample standard deviation over seeds (each seed's value in brackets, seed "
        "order; n/a: a run without a `policy_last.pt` or without evaluations). "
        f"The final policy (`policy_last.pt`) of each run flies {p.num_starts} test starts (seed {p.seed}) of each set "
        f"for {p.seconds:g} s; the validation columns are the runs' own in-training evaluations "
        "(`eval.validation_seed` starts).",
    ]
    return lines


def runs_sections(runs_dir, out: Path, protocol: TestProtocolConfig | None = None, by_variant=None) -> list[str]:
    """Table 2 and the learning curves (figs. 8-10) of every run (`summary.json`) below `runs_dir`
    (a directory or a list of them): the final policies flown on the test starts, the evaluations
    from the summaries, the episode returns from the TensorBoard events. Per-run figures go to
    `out`/table2.json. `by_variant`: runs already read (read_runs), flown here if not yet."""
    protocol = protocol or TestProtocolConfig()
    dirs = [Path(d) for d in runs_dir] if isinstance(runs_dir, (list, tuple)) else [Path(runs_dir)]
    runs_dir = ", ".join(str(d) for d in dirs)
    by_variant = read_runs(*dirs) if by_variant is None else by_variant
    if not by_variant:
        return ["## Ablation (Table 2)", f"No training runs (summary.json) under {runs_dir}.", ""]
    if any("test" not in r for runs in by_variant.values() for r in runs):
        fly_final_policies(by_variant, protocol)
    per_run = {
        v: [{k: (str(x) if k == "dir" else x) for k, x in r.items() if k != "history"} for r in runs]
        for v, runs in by_variant.items()
    }
    (out / "table2.json").write_text(json.dumps(per_run, indent=1))
    lines = ["## Ablation (Table 2)", f"Runs under `{runs_dir}`.", "", *table2(by_variant, protocol)]
    fig, axes = subplots(2, 3, figsize=(15, 7.6))
    for variant, runs in by_variant.items():
        frames = torch.tensor([h["frames"] for h in runs[0]["history"]], dtype=torch.float64) / 1e6
        minutes = torch.tensor([h["wall_seconds"] for h in runs[0]["history"]], dtype=torch.float64) / 60
        history = {
            key: [torch.tensor([h.get(key, float("nan")) for h in r["history"]]) for r in runs]
            for key in ("eval/success_rate", "eval/hover_error", "eval/attitude_error")
        }
        _plot_band(axes[0, 0], frames, history["eval/success_rate"], variant)
        _plot_band(axes[0, 1], minutes, history["eval/success_rate"], variant)
        _plot_band(axes[1, 0], frames, history["eval/hover_error"], variant)
        _plot_band(axes[1, 1], frames, history["eval/attitude_error"], variant)
        returns = [tb_scalars(r["dir"], "train/episode_return") for r in runs]
        steps = returns[0][0] / 1e6
        _plot_band(axes[0, 2], steps, [v for _, v in returns], variant)
        _plot_band(axes[1, 2], steps, [v.cumsum(0) for _, v in returns], variant)
    labels = (
        ("frames (M)", "success rate"),
        ("wall-clock (min)", "success rate"),
        ("frames (M)", "average episode return"),
        ("frames (M)", "hover error (m)"),
        ("frames (M)", "hover tilt (deg)"),
        ("frames (M)", "cumulative episode return"),
    )
    for ax, (xlabel, ylabel) in zip(axes.flat, labels, strict=True):
        ax.set_xlabel(xlabel)
        ax.set_ylabel(ylabel)
        ax.grid(alpha=0.3)
    if any(line.get_ydata().size and (line.get_ydata() > 0).any() for line in axes[1, 0].get_lines()):
        axes[1, 0].set_yscale("log")
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out / "learning_curves.png", dpi=110)
    lines += [
        "",
        "## Learning curves (figs. 8-10)",
        "Mean over seeds, band = min to max; evaluations every `eval.interval_frames` (success, and the "
        "hover error and tilt: the median over the successful flights of the mean distance to the goal and "
        "tilt over their last 2 s), episode returns per batch from TensorBoard (`train/episode_return`) "
        "and their running sum.",
        "",
        "![learning curves](learning_curves.png)",
        "",
    ]
    return lines


def write_report(
    out, controller=None, runs_dir=None, protocol: TestProtocolConfig | None = None, header: str = "", baselines=()
) -> Path:
    """report.md and its figures in `out`: the protocol suite for `controller` (a policy path or a
    controller name), the comparison with `baselines` (controller names), and Table 2 and the
    learning curves of the runs under `runs_dir`. protocol: starts, seconds and success rule
    (default: the paper's, on the test starts)."""
    from bfc.controllers import CONTROLLERS

    protocol = protocol or TestProtocolConfig()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    lines = ["# bfc evaluation report", "", header, ""]
    if controller is not None:
        policy_lines, flights = policy_sections(controller, out, protocol)
        lines += policy_lines
        label = "bfc" if str(controller) not in CONTROLLERS else str(controller)
        others = {b: b for b in baselines if b != label}
        if others:
            lines += controller_sections({label: controller, **others}, out, protocol, {label: flights})
    if runs_dir is not None:
        lines += runs_sections(Path(runs_dir), out, protocol)
    path = out / "report.md"
    path.write_text("\n".join(lines) + "\n")
    return path
