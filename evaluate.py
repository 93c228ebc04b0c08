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


if __name__ == "__main__":
    main()
