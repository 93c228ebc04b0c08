"""Evaluate a policy file or a classical controller on the paper's protocol.

    python evaluate.py policy=pretrained/policy.pt
    python evaluate.py policy=pretrained/policy.pt noise.kind=ou noise.std=0.05 noise.elements=position
    python evaluate.py controller=lee eval.num_starts=50
    python evaluate.py suite=paper policy=pretrained/policy.pt [runs=multirun/<date>/<time>]
    python evaluate.py suite=robust policy=pretrained/policy.pt baselines=[lee,lee_i,mpc]

The protocol's keys are `eval.*` (eval.seed=0: the test starts that the docs report; training
chooses policy.pt on its own eval.validation_seed=1 starts). A single evaluation writes
results.json (success count and rate, per-start outcome and time to success, errors after
success) and figures; suite=paper writes report.md, suite=robust robust.md (start sets harsh, any,
ground and model mismatch and wind, bfc.evaluation.suites) with robust.png and robust.json.
Every key is honoured or rejected in each mode; bad input ends with a one-line `error: ...` and exit status 2.
"""

import json
import sys
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from bfc.cli import fail, precheck
from bfc.config import EVALUATION_SUITES, EvaluateConfig, check_keys, check_protocol
from bfc.evaluation import CONTROLLERS, fly, protocol_starts
from bfc.evaluation.metrics import summarize

DEFAULTS = OmegaConf.structured(EvaluateConfig)


def _changed(cfg, key: str) -> bool:
    return OmegaConf.select(cfg, key) != OmegaConf.select(DEFAULTS, key)


def check(cfg) -> None:
    """Reject what the chosen mode would not use, and bad values, before anything flies."""
    check_keys(cfg, "evaluate")
    check_protocol(cfg.eval)
    if cfg.controller is not None and cfg.controller not in CONTROLLERS:
        raise ValueError(f"unknown controller {cfg.controller!r}; available: {', '.join(sorted(CONTROLLERS))}")
    if cfg.suite is None:
        if (cfg.policy is None) == (cfg.controller is None):
            raise ValueError(f"give exactly one of policy=<path to policy.pt> or controller=<{'|'.join(CONTROLLERS)}>")
        unused = [k for k in ("runs", "baselines") if _changed(cfg, k)]
        if unused:
            raise ValueError(f"{', '.join(unused)} only apply with suite=paper; a single evaluation does not use them")
        return
    if cfg.suite not in EVALUATION_SUITES:
        raise ValueError(f"suite must be one of {', '.join(EVALUATION_SUITES)}, got {cfg.suite!r}")
    s = cfg.suite
    if cfg.policy is not None and cfg.controller is not None:
        raise ValueError(f"suite={s} flies one policy= or controller= (the baselines go in baselines=[...])")
    if s == "robust" and cfg.runs is not None:
        raise ValueError("runs only applies with suite=paper")
    if cfg.policy is None and cfg.controller is None and (cfg.runs is None or s == "robust"):
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
    unknown = [b for b in cfg.baselines if b not in CONTROLLERS]
    if unknown:
        raise ValueError(f"unknown baselines {unknown}; available: {sorted(CONTROLLERS)}")


@hydra.main(config_path="conf", config_name="evaluate", version_base="1.3")
def main(cfg) -> None:
    out = Path(HydraConfig.get().runtime.output_dir)
    try:
        check(cfg)
        if cfg.suite == "robust":
            return run_robust(cfg, out)
        if cfg.suite is not None:
            return run_suite(cfg, out)
        controller = cfg.controller or cfg.policy
        e = cfg.eval
        starts = protocol_starts(e.num_starts, e.seed)
        t0 = time.perf_counter()
        flights = fly(
            controller,
            starts,
            goal=tuple(cfg.goal),
            seconds=e.seconds,
            noise=OmegaConf.to_container(cfg.noise),
            seed=e.seed,
        )
        wall = time.perf_counter() - t0
    except (ValueError, FileNotFoundError) as err:
        fail(err)
    results = {
        "controller": str(controller),
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


def run_suite(cfg, out: Path) -> None:
    from bfc.evaluation.report import write_report

    controller = cfg.controller or cfg.policy
    t0 = time.perf_counter()
    flown = [f"Controller: `{controller}`" if controller else None, f"runs: `{cfg.runs}`" if cfg.runs else None]
    header = "; ".join(f for f in flown if f) + f". Command: `python evaluate.py {' '.join(sys.argv[1:])}`."
    path = write_report(out, controller, cfg.runs, protocol=cfg.eval, header=header, baselines=list(cfg.baselines))
    print(f"report written to {path} in {time.perf_counter() - t0:.0f} s")


def run_robust(cfg, out: Path) -> None:
    from bfc.evaluation.suites import robust_figure, robust_results, robust_table

    controller = cfg.controller or cfg.policy
    label = cfg.controller or "bfc"
    controllers = {label: controller, **{b: b for b in cfg.baselines if b != label}}
    e = cfg.eval
    t0 = time.perf_counter()
    results = robust_results(controllers, num_starts=e.num_starts, seed=e.seed, protocol=e)
    (out / "robust.json").write_text(json.dumps(results, indent=1))
    robust_figure(results, out / "robust.png")
    lines = [
        "# Robustness: start sets, model mismatch and wind",
        "",
        f"Controller: `{controller}`. Command: `python evaluate.py {' '.join(sys.argv[1:])}`. "
        f"{e.num_starts} starts per suite (seed {e.seed}), {e.seconds:g} s, success = within {e.threshold:g} m on "
        f"every axis for {e.hold_seconds:g} s; hover error = median over the successful flights of the mean "
        "distance to the goal over the last 2 s. Suites: bfc.evaluation.suites.",
        "",
        *robust_table(results),
        "",
        "![robustness](robust.png)",
        "",
    ]
    (out / "robust.md").write_text("\n".join(lines))
    print(f"robust.md written to {out} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    precheck("evaluate")
    main()
