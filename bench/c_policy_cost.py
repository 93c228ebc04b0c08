"""What the C export (docs/export.md, "C export") costs and how close it flies to the torch policy.

    python bench/c_policy_cost.py [--policy pretrained/policy.pt|tiny] [--calls 200000] [--flights 100]

`--policy tiny`: the random 2x16 ELU policy (speed map, accelerations) of tests/test_export.py.

Prints, for the policy's exported header:
- the work per call counted from the layer sizes (multiply-adds, transcendental calls) and the
  weights' size;
- microseconds per call of the compiled `bfc_policy_step` on this machine: a C timing loop
  (`cc -std=c99 -O2`, clock_gettime around `--calls` calls, each fed the previous call's command
  and a moving position so that no call can be hoisted; best of 5 repeats);
- (the cost on a Cortex-M4F, the Crazyflie's core, is bench/cortex_m4_cost.py's: measured there);
- the parity with the torch policy on the 2000 rows tests/test_export.py checks the ONNX model on,
  and the success of `--flights` protocol starts flown through `CController` and by the torch policy.
"""

from __future__ import annotations

import argparse
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
from torch import nn

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # the parity rows and the torch reference of tests/test_export.py

from bfc.agent import load_policy  # noqa: E402
from bfc.agent.c_controller import CFLAGS, find_compiler  # noqa: E402
from bfc.export import CController, export_c  # noqa: E402

TIMING = r"""
#define _POSIX_C_SOURCE 199309L
#include <stdio.h>
#include <stdlib.h>
#include <time.h>
#include "policy.h"

int main(int argc, char **argv)
{
    const long calls = argc > 1 ? atol(argv[1]) : 100000;
    float odometry[18] = {0.1f, -0.2f, 1.4f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.0f, 0.05f, -0.05f, 0.3f};
    const float goal[3] = {0.0f, 0.0f, 1.5f};
    float checksum = 0.0f, best = 1e30f;
    bfc_policy_state state;
    int repeat;
    for (repeat = 0; repeat < 5; ++repeat) {
        struct timespec t0, t1;
        long i;
        float ns;
        bfc_policy_reset(&state);
        clock_gettime(CLOCK_MONOTONIC, &t0);
        for (i = 0; i < calls; ++i) {
            float speeds[4];
            odometry[0] = 0.1f + 1e-6f * (float)(i & 1023); /* a moving input: no call is hoisted */
            bfc_policy_update(&state, odometry, goal, speeds);
            checksum += speeds[0];
        }
        clock_gettime(CLOCK_MONOTONIC, &t1);
        ns = (float)((t1.tv_sec - t0.tv_sec) * 1e9 + (t1.tv_nsec - t0.tv_nsec)) / (float)calls;
        if (ns < best) best = ns;
    }
    printf("%.1f %g\n", best, checksum);
    return 0;
}
"""


def counts(policy: Path) -> dict:
    spec, net = load_policy(policy)
    linears = [m for m in net.mlp if isinstance(m, nn.Linear)]
    hidden = sum(m.out_features for m in linears[:-1])
    transcendental = 0 if spec.observation == "odometry" else 6  # cos and sin of roll, pitch, yaw
    transcendental += 2 if spec.observation == "odometry" and spec.position_integral else 0
    transcendental += hidden if spec.activation in ("tanh", "elu") else 0  # tanhf / expm1f per unit
    transcendental += 4 if spec.squash else 0
    transcendental += 4 if spec.action_map == "thrust" else 0  # sqrtf per motor
    return {
        "spec": spec,
        "sizes": [linears[0].in_features] + [m.out_features for m in linears],
        "macs": sum(m.in_features * m.out_features for m in linears),
        "parameters": sum(m.weight.numel() + m.bias.numel() for m in linears),
        "transcendental": transcendental,
    }


def time_calls(header: Path, calls: int) -> float:
    """Nanoseconds per `bfc_policy_step` call (best of 5 loops of `calls`), compiled here."""
    source = header.parent / "timing.c"
    source.write_text(TIMING)
    binary = header.parent / "timing"
    subprocess.run([find_compiler(), *CFLAGS, str(source), "-o", str(binary), "-lm"], check=True)
    out = subprocess.run([str(binary), str(calls)], check=True, capture_output=True, text=True).stdout
    return float(out.split()[0])


def parity(policy: Path, header: Path) -> tuple[float, float]:
    from tests.export_helpers import parity_rows, torch_reference

    spec, _ = load_policy(policy)
    odometry, goal, previous, integral, history = parity_rows(spec)  # the export tests' rows
    expected, _ = torch_reference(policy, odometry, goal, previous, integral, history)
    speeds, _ = CController(header).step(
        odometry.numpy(), goal.numpy(), previous.numpy(), integral.numpy(), None if history is None else history.numpy()
    )
    diff = float(np.abs(speeds - expected.numpy()).max())
    return diff, diff / spec.nominal_airframe.hover_speed


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--policy", default=str(ROOT / "pretrained" / "policy.pt"), help="a policy.pt, or tiny")
    p.add_argument("--calls", type=int, default=200_000)
    p.add_argument("--flights", type=int, default=100, help="protocol starts to fly (0: none)")
    args = p.parse_args()
    cc = find_compiler()
    version = subprocess.run([cc, "--version"], capture_output=True, text=True).stdout.splitlines()[0]
    with tempfile.TemporaryDirectory(prefix="bfc-c-bench-") as tmp:
        if args.policy == "tiny":
            from tests.test_export import tiny_policy

            policy = tiny_policy(Path(tmp) / "tiny.pt")
        else:
            policy = Path(args.policy)
        header = export_c(policy, Path(tmp) / "policy.h")
        c = counts(policy)
        spec = c["spec"]
        print(f"# {policy.name}: MLP {' -> '.join(map(str, c['sizes']))} {spec.activation}, {spec.action_map} map")
        print(f"# {platform.machine()}, {platform.processor() or 'cpu'}; {version}; flags {' '.join(CFLAGS)}")
        print(f"multiply-adds per call: {c['macs']} (sum of in x out over the Linear layers)")
        print(f"transcendental calls per call: {c['transcendental']} (sinf/cosf, activations, sqrtf)")
        print(f"weights: {c['parameters']} floats = {4 * c['parameters'] / 1024:.1f} KiB (static const: flash)")
        print(f"header: {header.stat().st_size / 1024:.0f} KiB of C")
        ns = time_calls(header, args.calls)
        print(f"here: {ns / 1000:.2f} us per call ({args.calls} calls in a C loop, best of 5)")
        print("on a Cortex-M4F: python bench/cortex_m4_cost.py (instructions counted on an emulated one)")
        diff, hovers = parity(policy, header)
        print(f"parity, 2000 rows of tests/test_export.py: max |C - torch| = {diff:.5f} rad/s ({hovers:.1e} hover)")
        if args.flights:
            from bfc.evaluation import fly, protocol_starts, success

            starts = protocol_starts(args.flights, seed=0)
            controller = CController(header)
            by_torch = fly(str(policy), starts, seconds=10.0)
            by_c = fly(controller, starts, seconds=10.0, control_hz=controller.control_hz)
            same = success(by_c).tolist() == success(by_torch).tolist()
            gap = (by_c.get(("state", "position")) - by_torch.get(("state", "position"))).abs().max()
            print(
                f"protocol_starts({args.flights}, seed=0), 10 s: C {int(success(by_c).sum())}/{args.flights}, "
                f"torch {int(success(by_torch).sum())}/{args.flights}, same per start: {same}, "
                f"max position difference {float(gap):.1e} m"
            )


if __name__ == "__main__":
    main()
