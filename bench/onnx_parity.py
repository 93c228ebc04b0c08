"""How close an ONNX export computes to its torch policy: docs/export.md's parity table.

    python bench/onnx_parity.py [pretrained/policy.pt ...]

For each policy file, exports it (`bfc.export.export_onnx`) and runs the 2000 rows
tests/test_export.py asserts on (1000 over the protocol's states and beyond, 1000 near hover;
integrals in +-0.5 m s; older commands drawn from the rows' previous ones for a policy with a
command history) through onnxruntime and through the torch reference; prints the largest
difference in rad/s, in hover speeds and in the policy's action units, and the share of commands
strictly inside (0, max). Deterministic; a few seconds.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
from pathlib import Path

import numpy as np
import torch

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))  # tests.export_helpers: the reference the test uses

from bfc.agent import load_policy  # noqa: E402
from bfc.export import export_onnx  # noqa: E402


def parity(policy: Path) -> dict:
    import onnxruntime as ort

    from tests.export_helpers import parity_rows, torch_reference

    spec, _ = load_policy(policy)
    hover, top = spec.nominal_airframe.hover_speed, spec.nominal_airframe.max_rotor_speed
    odometry, goal, previous, integral, history = parity_rows(spec)
    expected, _ = torch_reference(policy, odometry, goal, previous, integral, history)
    with tempfile.TemporaryDirectory() as d:
        session = ort.InferenceSession(str(export_onnx(policy, Path(d) / "p.onnx")), providers=["CPUExecutionProvider"])
    feeds = {"odometry": odometry.numpy(), "goal": goal.numpy(), "previous_motor_speeds": previous.numpy()}
    if spec.position_integral:
        feeds["position_error_integral"] = integral.numpy()
    if history is not None:
        feeds["motor_speed_history"] = history.numpy()
    got = session.run(None, feeds)[0]
    rad = float(np.abs(got - expected.numpy()).max())
    to_action = spec.make_action_map().to_action
    action = float((to_action(torch.from_numpy(got)) - to_action(expected)).abs().max())
    inside = float(((expected > 0) & (expected < top)).float().mean())
    return {"rad_s": rad, "hover_speeds": rad / hover, "action_units": action, "inside": inside}


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("policies", nargs="*", default=["pretrained/policy.pt"], help="policy files (default: shipped)")
    args = p.parse_args()
    columns = ["policy", "max abs difference", "in hover speeds", "in action units"]
    columns.append("motor commands strictly inside (0, max)")
    print("| " + " | ".join(columns) + " |")
    print("|---|---|---|---|---|")
    for path in args.policies:
        file = Path(path) if Path(path).exists() else ROOT / path  # run from anywhere
        r = parity(file)
        print(
            f"| {path} | {r['rad_s']:.2g} rad/s | {r['hover_speeds']:.2g} | {r['action_units']:.2g} "
            f"| {100 * r['inside']:.0f}% |"
        )


if __name__ == "__main__":
    main()
