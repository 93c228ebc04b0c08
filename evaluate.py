"""Evaluate a policy file or a classical controller on the paper's protocol.

    python evaluate.py policy=pretrained/policy.pt
    python evaluate.py policy=pretrained/policy.pt noise.kind=ou noise.std=0.05 noise.elements=position
    python evaluate.py controller=lee eval.num_starts=50
    python evaluate.py suite=paper policy=pretrained/policy.pt [runs=multirun/<date>/<time>]
    python evaluate.py suite=robust policy=pretrained/policy.pt baselines=[lee,lee_i,mpc]
    python evaluate.py policy=pretrained/policy.pt sim=rotorpy      (RotorPy instead of MuJoCo)

The protocol's keys are `eval.*` (eval.seed=0: the test starts that the docs report; training
chooses policy.pt on its own eval.validation_seed=1 starts). A single evaluation writes
results.json (success count and rate, per-start outcome and time to success, errors after
success) and figures; suite=paper writes report.md, suite=robust robust.md (start sets harsh, any,
ground and model mismatch and wind, bfc.evaluation.suites) with robust.png and robust.json.
Every key is honoured or rejected in each mode; bad input ends with a one-line `error: ...` and exit status 2.
"""

import dataclasses
import json
import sys
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

import bfc.headless_gl  # noqa: F401  (before mujoco is imported: MUJOCO_GL=egl without a display)
from bfc import lifetime
from bfc.cli import fail, precheck
from bfc.config import (
    CONTROLLER_NAMES,
    EVALUATION_SUITES,
    ROTORPY_AIRFRAMES,
    SIMULATORS,
    EvaluateConfig,
    check_keys,
    check_protocol,
)

DEFAULTS = OmegaConf.structured(EvaluateConfig)
SIM_NOTES = {
    "mujoco": "bfc's MuJoCo env",
    "rotorpy": "RotorPy, {airframe} airframe (docs/evaluation.md, Another simulator: RotorPy; the wind row is "
    "the air whose drag at hover is the row's force)",
}


def _changed(cfg, key: str) -> bool:
    return OmegaConf.select(cfg, key) != OmegaConf.select(DEFAULTS, key)


def nominal_airframe(cfg):
    """The airframe of the flights: the policy's own, else `airframe=` (the Hummingbird by default)."""
    from bfc.config import airframe_params
    from bfc.envs import AirframeParams

    if cfg.policy is not None:
        from bfc.evaluation.flying import airframe_of

        own = airframe_of(cfg.policy)
        if cfg.airframe is not None and airframe_params(cfg.airframe).name != own.name:
            raise ValueError(
                f"{cfg.policy} flies the airframe it was trained on ({own.name}); airframe= is for controller= alone"
            )
        return own
    return airframe_params(cfg.airframe) if cfg.airframe is not None else AirframeParams()


def check(cfg) -> None:
    """Reject what the chosen mode would not use, and bad values, before anything flies."""
    check_keys(cfg, "evaluate")
    check_protocol(cfg.eval)
    check_sim(cfg)
    check_video(cfg)
    if cfg.controller is not None and cfg.controller not in CONTROLLER_NAMES:
        raise ValueError(f"unknown controller {cfg.controller!r}; available: {', '.join(sorted(CONTROLLER_NAMES))}")
    if cfg.suite is None:
        if (cfg.policy is None) == (cfg.controller is None):
            names = "|".join(CONTROLLER_NAMES)
            raise ValueError(f"give exactly one of policy=<path to policy.pt> or controller=<{names}>")
        unused = [k for k in ("runs", "baselines") if _changed(cfg, k)]
        if unused:
            raise ValueError(f"{', '.join(unused)} only apply with suite=paper; a single evaluation does not use them")
        return
    if cfg.suite not in EVALUATION_SUITES:
        raise ValueError(f"suite must be one of {', '.join(EVALUATION_SUITES)}, got {cfg.suite!r}")
    s = cfg.suite
    if cfg.policy is not None and cfg.controller is not None:
        raise ValueError(f"suite={s} flies one policy= or controller= (the baselines go in baselines=[...])")
    if s != "paper" and cfg.runs is not None:
        raise ValueError("runs only applies with suite=paper")
    if cfg.policy is None and cfg.controller is None and (cfg.runs is None or s != "paper"):
        more = " and/or runs=<directory of runs>" if s == "paper" else ""
        raise ValueError(f"suite={s} needs policy=<path> or controller=<name>{more}")
    unused = [k for k in ("noise", "goal", "figures") if _changed(cfg, k)]
    if unused:
        raise ValueError(
            f"{', '.join(unused)} do not apply with suite={s} (it flies the protocol's goal, its own "
            "conditions, and always writes its figures)"
        )
    if cfg.runs is not None and not Path(cfg.runs).is_dir():
        raise FileNotFoundError(f"runs={cfg.runs} is not a directory")
    unknown = [b for b in cfg.baselines if b not in CONTROLLER_NAMES]
    if unknown:
        raise ValueError(f"unknown baselines {unknown}; available: {sorted(CONTROLLER_NAMES)}")


def check_sim(cfg) -> None:
    """sim=rotorpy (bfc.evaluation.rotorpy_sim): RotorPy installed, and only what it flies."""
    if cfg.sim not in SIMULATORS:
        raise ValueError(f"sim must be one of {', '.join(SIMULATORS)}, got {cfg.sim!r}")
    if cfg.rotorpy_airframe not in ROTORPY_AIRFRAMES:
        allowed = ", ".join(ROTORPY_AIRFRAMES)
        raise ValueError(f"rotorpy_airframe must be one of {allowed}, got {cfg.rotorpy_airframe!r}")
    if cfg.sim != "rotorpy":
        if _changed(cfg, "rotorpy_airframe"):
            raise ValueError("rotorpy_airframe only applies with sim=rotorpy")
        return
    if cfg.suite in ("paper", "hardware"):
        raise ValueError(
            f"sim=rotorpy flies the protocol (no suite) or suite=robust; suite={cfg.suite} flies MuJoCo only"
        )
    if _changed(cfg, "noise"):
        raise ValueError("noise does not apply with sim=rotorpy (RotorPy flights see the true odometry)")
    from bfc.evaluation.rotorpy_sim import require_rotorpy

    require_rotorpy()


VIDEO_KEYS = ("video_starts", "video_pick", "video_camera", "video_seconds", "video_fps", "video_width", "video_height")


def check_video(cfg) -> None:
    """video=true (bfc.evaluation.video): a single evaluation or suite=robust in MuJoCo, PyAV installed."""
    if not cfg.video:
        unused = [k for k in VIDEO_KEYS if _changed(cfg, k)]
        if unused:
            raise ValueError(f"{', '.join(unused)} only apply with video=true")
        return
    from bfc.evaluation.video import check_options, writer_missing

    if cfg.suite == "paper" or cfg.sim != "mujoco":
        raise ValueError("video=true films a single evaluation, suite=robust or suite=hardware flown in MuJoCo")
    c = cfg
    check_options(
        c.video_fps, c.video_width, c.video_height, c.video_starts, c.video_camera, c.video_pick, c.video_seconds
    )
    missing = writer_missing()
    if missing:
        raise ValueError(missing)


def film(cfg, out: Path, kept: dict) -> None:
    """Render the kept clips ({row: clips}; "" for a single evaluation) after the numbers are written;
    no OpenGL renderer is one `error: ...` line (what to install) and exit status 2."""
    from bfc.evaluation.video import RendererUnavailable, slug, write_video

    t0, frames, written = time.perf_counter(), 0, []
    try:
        for name, clips in kept.items():
            stem = out / (f"video_{slug(name)}" if name else "video")
            paths, n = write_video(
                clips, stem, cfg.video_fps, cfg.video_width, cfg.video_height, cfg.video_camera, cfg.video_seconds
            )
            frames, written = frames + n, written + [p.name for p in paths]
    except RendererUnavailable as err:
        fail(err)
    print(f"{frames} video frames rendered in {time.perf_counter() - t0:.1f} s: {', '.join(written)}")


@hydra.main(config_path="conf", config_name="evaluate", version_base="1.3")
def main(cfg) -> None:
    out = Path(HydraConfig.get().runtime.output_dir)
    try:
        check(cfg)
        # torch, TorchRL and MuJoCo load only once the command line passed its checks
        from bfc.evaluation import fly, protocol_starts
        from bfc.evaluation.metrics import summarize

        if cfg.suite in ("robust", "hardware"):
            return run_robust(cfg, out)
        if cfg.suite is not None:
            return run_suite(cfg, out)
        controller = cfg.controller or cfg.policy
        e = cfg.eval
        starts = protocol_starts(e.num_starts, e.seed)
        nominal = nominal_airframe(cfg)
        t0 = time.perf_counter()
        if cfg.sim == "rotorpy":
            from bfc.evaluation.rotorpy_sim import fly_rotorpy

            flights = fly_rotorpy(
                controller, starts, tuple(cfg.goal), e.seconds, airframe=cfg.rotorpy_airframe, nominal=nominal
            )
        else:
            flights = fly(
                controller,
                starts,
                goal=tuple(cfg.goal),
                seconds=e.seconds,
                noise=OmegaConf.to_container(cfg.noise),
                seed=e.seed,
                nominal=dataclasses.asdict(nominal),
            )
        wall = time.perf_counter() - t0
    except (ValueError, FileNotFoundError) as err:
        fail(err)
    results = {
        "controller": str(controller),
        "airframe": nominal.name,
        "sim": cfg.sim if cfg.sim == "mujoco" else f"rotorpy ({cfg.rotorpy_airframe} airframe)",
        "noise": OmegaConf.to_container(cfg.noise),
        "protocol": OmegaConf.to_container(cfg.eval),
        "flight_wall_seconds": round(wall, 2),
        **summarize(flights, e.threshold, e.hold_seconds),
    }
    (out / "results.json").write_text(json.dumps(results, indent=1))
    if cfg.figures:
        from bfc.evaluation.plots import flight_figures

        flight_figures(flights, out)
    print(
        f"{results['success']}/{results['starts']} successful ({results['success_rate']:.0%}), "
        f"{results['crashes']} crashes; flights took {wall:.1f} s; written to {out}"
    )
    if cfg.video:
        from bfc.evaluation.video import clips_from_flights, pick_starts

        chosen = pick_starts(starts, cfg.video_starts, cfg.video_pick)
        film(cfg, out, {"": clips_from_flights(flights, starts, chosen, e.threshold, airframe=nominal)})


def run_suite(cfg, out: Path) -> None:
    from bfc.evaluation.report import write_report

    controller = cfg.controller or cfg.policy
    t0 = time.perf_counter()
    flown = [f"Controller: `{controller}`" if controller else None, f"runs: `{cfg.runs}`" if cfg.runs else None]
    header = "; ".join(f for f in flown if f) + f". Command: `python evaluate.py {' '.join(sys.argv[1:])}`."
    path = write_report(out, controller, cfg.runs, protocol=cfg.eval, header=header, baselines=list(cfg.baselines))
    print(f"report written to {path} in {time.perf_counter() - t0:.0f} s")


def robust_keeper(
    kept: dict, label: str, count: int, pick: str, threshold: float, num_starts: int, seed: int, airframe=None
):
    """An `on_flights` for `robust_results`: keeps, in kept[row], the clips of `label`'s chosen starts
    of each row (the other controllers' flights are not filmed)."""
    from bfc.evaluation.suites import condition
    from bfc.evaluation.video import clips_from_flights, pick_starts

    def keep(name: str, flown: str, flights) -> None:
        if flown != label:
            return
        starts = condition(name).starts_for(num_starts, seed, airframe)
        chosen = pick_starts(starts, count, pick)
        kept[name] = clips_from_flights(flights, starts, chosen, threshold, label=name, airframe=airframe)

    return keep


TITLES = {
    "robust": "Robustness: start sets, model mismatch and wind",
    "hardware": "What hardware brings: latency, estimator noise and gyro bias, a throw",
}


def run_robust(cfg, out: Path) -> None:
    """suite=robust (robust.md/.json/.png) or suite=hardware (hardware.md/.json/.png)."""
    from bfc.evaluation.suites import SUITES, robust_figure, robust_results, robust_table

    suite = cfg.suite
    controller = cfg.controller or cfg.policy
    label = cfg.controller or "bfc"
    controllers = {label: controller, **{b: b for b in cfg.baselines if b != label}}
    e = cfg.eval
    nominal = nominal_airframe(cfg)
    t0 = time.perf_counter()
    kept, keep = {}, None
    if cfg.video:  # the chosen starts of each row, flown by the policy (or controller) under test
        keep = robust_keeper(kept, label, cfg.video_starts, cfg.video_pick, e.threshold, e.num_starts, e.seed, nominal)
    if cfg.sim == "rotorpy":
        from bfc.evaluation.rotorpy_sim import robust_results_rotorpy

        results = robust_results_rotorpy(controllers, None, e.num_starts, e.seed, e, cfg.rotorpy_airframe, nominal)
    else:
        names = list(SUITES[suite])
        results = robust_results(
            controllers, names, num_starts=e.num_starts, seed=e.seed, protocol=e, on_flights=keep, airframe=nominal
        )
    (out / f"{suite}.json").write_text(json.dumps(results, indent=1))
    robust_figure(results, out / f"{suite}.png")
    lines = [
        f"# {TITLES[suite]}",
        "",
        f"Controller: `{controller}`. Airframe: {nominal.name}. "
        f"Simulator: {SIM_NOTES[cfg.sim].format(airframe=cfg.rotorpy_airframe)}. "
        f"Command: `python evaluate.py {' '.join(sys.argv[1:])}`. "
        f"{e.num_starts} starts per suite (seed {e.seed}), {e.seconds:g} s, success = within {e.threshold:g} m on "
        f"every axis for {e.hold_seconds:g} s; hover error = median over the successful flights of the mean "
        "distance to the goal over the last 2 s. Suites: bfc.evaluation.suites.",
        "",
        *robust_table(results),
        "",
        f"![{suite}]({suite}.png)",
        "",
    ]
    (out / f"{suite}.md").write_text("\n".join(lines))
    print(f"{suite}.md written to {out} in {time.perf_counter() - t0:.0f} s")
    if cfg.video:
        film(cfg, out, kept)


if __name__ == "__main__":
    precheck("evaluate")
    try:
        main()
    except KeyboardInterrupt:
        print("interrupted: nothing was written for the flights in progress", file=sys.stderr)
        sys.exit(lifetime.INTERRUPTED)
