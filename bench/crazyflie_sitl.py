"""The Crazyflie app's core in the loop against its torch policy, on 100 test starts per set: the
table of docs/export.md ("Software in the loop").

    python bench/crazyflie_sitl.py [--policy pretrained/crazyflie.pt] [--starts 100]

Exports the app (`--format crazyflie`), compiles its core with the system C compiler and flies it
through `fly` at the firmware's THRUST_MAX and with a force of 1 as the trained full thrust,
beside the torch policy on the same starts. Deterministic; needs `cc`.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

from bfc.agent import read_policy
from bfc.agent.crazyflie_app import FIRMWARE_THRUST_MAX
from bfc.evaluation import fly, protocol_starts
from bfc.evaluation.suites import any_starts, score
from bfc.export import CrazyflieAppController, export_crazyflie


def describe(s: dict) -> str:
    hover = "n/a" if s["hover_error_m"] is None else f"{100 * s['hover_error_m']:.3f} cm"
    return f"{s['success_rate']:.2f}, {s['crashes']} crashes, hover {hover}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", default="pretrained/crazyflie.pt")
    parser.add_argument("--starts", type=int, default=100)
    args = parser.parse_args()
    spec = read_policy(args.policy).spec
    airframe = spec.nominal_airframe
    full = airframe.motor_constant * airframe.max_rotor_speed**2
    print(
        f"{args.policy}: trained full thrust {full:.5f} N per motor, the firmware's THRUST_MAX {FIRMWARE_THRUST_MAX} N"
    )
    print(
        "| set | torch policy | the app's core at THRUST_MAX | largest (median) position difference | "
        "with the trained full thrust: largest difference |"
    )
    print("|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as tmp:
        app = export_crazyflie(args.policy, Path(tmp) / "bfc_app")
        nominal = dataclasses.asdict(airframe)
        for name, starts in (
            ("protocol", protocol_starts(args.starts, seed=0)),
            ("any attitude", any_starts(args.starts, seed=0)),
        ):
            by_torch = fly(args.policy, starts, seconds=10.0)
            position = by_torch.get(("state", "position"))
            row = [name, describe(score(by_torch))]
            for thrust_max in (None, full):
                controller = CrazyflieAppController(app, thrust_max=thrust_max)
                flights = fly(controller, starts, seconds=10.0, control_hz=spec.control_hz, nominal=nominal)
                gap = (flights.get(("state", "position")) - position).norm(dim=-1).amax(-1)  # per flight, m
                if thrust_max is None:
                    row += [describe(score(flights)), f"{1000 * gap.max():.1f} mm ({1000 * gap.median():.1f} mm)"]
                else:
                    row.append(f"{1e6 * gap.max():.1f} um")
            print("| " + " | ".join(row) + " |")


if __name__ == "__main__":
    main()
