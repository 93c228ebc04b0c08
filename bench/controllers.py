"""BFC against the classical baselines on the protocol's starts: success, success by initial tilt,
time to success, errors and compute time per control step (one call for the whole batch).

    python bench/controllers.py [--policy pretrained/policy.pt] [--starts 100] [--out DIR]

Flies the policy at its own rate and the baselines (their tuned gains) at the paper's 250 Hz, each
with the default heading mode (hold the current heading: the task is yaw-free) and with a fixed heading of yaw 0.
Prints the Markdown tables of the evaluation report; the figures go to --out.
"""

from __future__ import annotations

import argparse
import platform
import tempfile
import time
from pathlib import Path

import torch

from bfc.config import TestProtocolConfig
from bfc.controllers import LeeGains, MPCParams, build
from bfc.envs import AirframeParams
from bfc.evaluation.flying import PROTOCOL_HZ
from bfc.evaluation.report import controller_sections

ROOT = Path(__file__).resolve().parents[1]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", default=str(ROOT / "pretrained" / "policy.pt"))
    p.add_argument("--starts", type=int, default=100)
    p.add_argument("--out", default=None)
    args = p.parse_args()
    airframe, dt = AirframeParams(), 1.0 / PROTOCOL_HZ
    controllers = {
        "bfc": args.policy,
        "mpc": "mpc",
        "lee": "lee",
        "lee_i": "lee_i",
        # the same tuned gains (bfc.controllers.tuned) with the heading held at yaw 0
        "mpc_yaw0": build("mpc", airframe, dt, config=MPCParams(yaw=0.0)),
        "lee_yaw0": build("lee", airframe, dt, config=LeeGains(yaw=0.0)),
    }
    out = Path(args.out or tempfile.mkdtemp(prefix="bfc-controllers-"))
    out.mkdir(parents=True, exist_ok=True)
    print(f"# {platform.machine()}, torch {torch.__version__}; {args.starts} protocol starts; figures in {out}")
    t0 = time.perf_counter()
    print(
        "\n".join(
            line
            for line in controller_sections(controllers, out, TestProtocolConfig(num_starts=args.starts))
            if not line.startswith("![")
        )
    )
    print(f"all flights took {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
