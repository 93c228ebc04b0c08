"""Evaluate a policy file or a classical controller on the paper's protocol.

    python evaluate.py policy=pretrained/policy.pt
    python evaluate.py policy=pretrained/policy.pt noise.kind=ou noise.std=0.05 noise.elements=position

Writes results.json (success count and rate, per-start outcome and time to success, errors after
success) and figures into the Hydra run directory.
"""

import json
import sys
import time
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from omegaconf import OmegaConf

from bfc.evaluation import CONTROLLERS, fly, protocol_starts
from bfc.evaluation.metrics import summarize


@hydra.main(config_path="conf", config_name="evaluate", version_base="1.3")
def main(cfg) -> None:
    out = Path(HydraConfig.get().runtime.output_dir)
    if cfg.suite is not None:
        return run_suite(cfg, out)
    try:
        if (cfg.policy is None) == (cfg.controller is None):
            raise ValueError(
                f"give exactly one of policy=<path to policy.pt> or controller=<{'|'.join(CONTROLLERS) or 'name'}>"
            )
        if cfg.controller is not None and cfg.controller not in CONTROLLERS:
            raise ValueError(f"unknown controller {cfg.controller!r}; available: {sorted(CONTROLLERS) or 'none yet'}")
        controller = cfg.controller or cfg.policy
        starts = protocol_starts(cfg.num_starts, cfg.seed)
        t0 = time.perf_counter()
        flights = fly(
            controller,
            starts,
            goal=tuple(cfg.goal),
            seconds=cfg.seconds,
            noise=OmegaConf.to_container(cfg.noise),
            seed=cfg.seed,
        )
        wall = time.perf_counter() - t0
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    results = {
        "controller": str(controller),
        "noise": OmegaConf.to_container(cfg.noise),
        "seconds": cfg.seconds,
        "flight_wall_seconds": round(wall, 2),
        **summarize(flights, cfg.threshold, cfg.hold_seconds),
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

    if cfg.suite != "paper":
        print(f"error: suite must be 'paper', got {cfg.suite!r}", file=sys.stderr)
        sys.exit(2)
    controller = cfg.controller or cfg.policy
    try:
        if controller is None and cfg.runs is None:
            raise ValueError("suite=paper needs policy=<path>, controller=<name> and/or runs=<directory of runs>")
        if cfg.runs is not None and not Path(cfg.runs).is_dir():
            raise FileNotFoundError(f"runs={cfg.runs} is not a directory")
        t0 = time.perf_counter()
        header = (
            f"Controller: `{controller}`; runs: `{cfg.runs}`. Command: `python evaluate.py {' '.join(sys.argv[1:])}`."
        )
        unknown = [b for b in cfg.baselines if b not in CONTROLLERS]
        if unknown:
            raise ValueError(f"unknown baselines {unknown}; available: {sorted(CONTROLLERS)}")
        path = write_report(
            out, controller, cfg.runs, cfg.num_starts, cfg.seed, header=header, baselines=list(cfg.baselines)
        )
    except (ValueError, FileNotFoundError) as err:
        print(f"error: {err}", file=sys.stderr)
        sys.exit(2)
    print(f"report written to {path} in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
