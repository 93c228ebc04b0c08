"""Would filtering the estimate the policy reads lower `suite=hardware`'s estimator row?

    python bench/estimator_filter.py [pretrained/policy.pt] [--seed 1 (validation starts)]

Exports the policy to ONNX and flies it (as flight firmware would: `OnnxController`) on the
protocol's starts under `ESTIMATOR_NOISE`, with a filter between the estimate and the policy on
the position and velocity (the white noise that puts most of the centimetre there,
bench/estimator_noise_parts.py): none, an exponential average of the position (weight `a` on
each new estimate), a complementary filter (the position carried forward by the velocity,
corrected by `a` of the estimate's error), or one on both (the velocity carried forward by the
estimated acceleration, the position by that filtered velocity, each corrected by `a`). Flies the
policy's own airframe at its own rate. Prints a Markdown table of success and hover error.
Deterministic; about 10 s per row on 2 cores.

What it tells: a filter removes noise above its corner frequency only; whatever lies within the
hover loop's own bandwidth the policy still follows, and its hover error stays.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
from pathlib import Path

import torch
from tensordict.nn import TensorDictModuleBase

from bfc import keys
from bfc.agent import load_policy
from bfc.agent.onnx import OnnxController
from bfc.evaluation.flying import fly
from bfc.evaluation.protocol import TEST_SEED
from bfc.evaluation.suites import ESTIMATOR_NOISE, START_SETS, score
from bfc.export import export_onnx

FILTERS = [("none", None, 1.0), ("average", "average", 0.5), ("average", "average", 0.3)]
FILTERS += [("complementary", "complementary", a) for a in (0.3, 0.1, 0.02)]
FILTERS += [("complementary, position and velocity", "both", a) for a in (0.3, 0.1)]


class FilteredEstimate(TensorDictModuleBase):
    """`controller` reading a filtered position (and velocity, for "both") instead of the estimate's."""

    def __init__(self, controller, kind: str, weight: float, dt: float):
        super().__init__()
        self.controller, self.kind, self.weight, self.dt = controller, kind, weight, dt
        self.in_keys, self.out_keys = controller.in_keys, controller.out_keys
        self.position: torch.Tensor | None = None
        self.velocity: torch.Tensor | None = None

    def begin_flight(self) -> None:
        self.position = None
        self.controller.begin_flight()

    def forward(self, td):
        odometry = td.get(keys.ODOMETRY)
        measured, velocity = odometry[..., keys.ODOM_POSITION], odometry[..., keys.ODOM_LINEAR_VELOCITY]
        if self.position is None or self.position.shape != measured.shape:
            self.position, self.velocity = measured.clone(), velocity.clone()
        else:
            if self.kind == "both":
                prior = self.velocity + self.dt * odometry[..., keys.ODOM_LINEAR_ACCELERATION]
                self.velocity = prior + self.weight * (velocity - prior)
            else:
                self.velocity = velocity
            prior = self.position + (self.dt * self.velocity if self.kind != "average" else 0.0)
            self.position = prior + self.weight * (measured - prior)
        td.set(keys.ODOMETRY, torch.cat([self.position, self.velocity, odometry[..., 6:]], -1))
        self.controller(td)
        return td.set(keys.ODOMETRY, odometry)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policy", nargs="?", default="pretrained/policy.pt")
    p.add_argument("--seed", type=int, default=TEST_SEED, help="the starts' seed (0: the test starts)")
    p.add_argument("--num-starts", type=int, default=100)
    args = p.parse_args()
    spec, _ = load_policy(args.policy)
    starts = START_SETS["protocol"](args.num_starts, args.seed)
    print(f"# {args.policy}: protocol starts (seed {args.seed}), ESTIMATOR_NOISE, {args.num_starts} flights of 10 s")
    print("| filter | a | success | hover error |\n|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        onnx = export_onnx(args.policy, Path(d) / "policy.onnx")
        for label, kind, weight in FILTERS:
            controller = OnnxController(onnx)
            if kind is not None:
                controller = FilteredEstimate(controller, kind, weight, 1.0 / spec.control_hz)
            # a module flies the Hummingbird unless told the policy's own airframe
            flight = {"control_hz": spec.control_hz, "nominal": dataclasses.asdict(spec.nominal_airframe)}
            s = score(fly(controller, starts, seconds=10.0, noise=ESTIMATOR_NOISE, seed=args.seed, **flight))
            error = "n/a" if s["hover_error_m"] is None else f"{100 * s['hover_error_m']:.3f} cm"
            print(f"| {label} | {weight:g} | {s['success_rate']:.2f} | {error} |", flush=True)


if __name__ == "__main__":
    main()
