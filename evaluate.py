"""Evaluate a policy file or a classical controller on the paper's protocol.

    python evaluate.py policy=pretrained/policy.pt
    python evaluate.py policy=pretrained/policy.pt noise.kind=ou noise.std=0.05 noise.elements=position
    python evaluate.py controller=lee eval.num_starts=50
    python evaluate.py suite=paper policy=pretrained/policy.pt [runs=multirun/<date>/<time>]

The protocol's keys are the training config's `eval` section (eval.seed=0: the test starts that
the docs report; training chooses policy.pt on eval.seed=1). A single evaluation writes
results.json (success count and rate, per-start outcome and time to success, errors after
success) and figures; suite=paper writes report.md. Every key is honoured or rejected in each
mode; bad input ends with a one-line `error: ...` and exit status 2.
"""

import json
import sys
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from bfc.config import SUITES, EvaluateConfig, check_keys, check_protocol
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
    if cfg.suite not in SUITES:
        raise ValueError(f"suite must be one of {', '.join(SUITES)}, got {cfg.suite!r}")
    if cfg.policy is not None and cfg.controller is not None:
        raise ValueError("suite=paper flies one policy= or controller= (the baselines go in baselines=[...])")
    if cfg.policy is None and cfg.controller is None and cfg.runs is None:
        raise ValueError("suite=paper needs policy=<path>, controller=<name> and/or runs=<directory of runs>")
    unused = [k for k in ("noise", "goal", "figures") if _changed(cfg, k)]
    if unused:
        raise ValueError(
            f"{', '.join(unused)} do not apply with suite=paper (it flies the protocol's goal, its own noise "
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
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
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
    header = f"Controller: `{controller}`; runs: `{cfg.runs}`. Command: `python evaluate.py {' '.join(sys.argv[1:])}`."
    path = write_report(out, controller, cfg.runs, protocol=cfg.eval, header=header, baselines=list(cfg.baselines))
    print(f"report written to {path} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
