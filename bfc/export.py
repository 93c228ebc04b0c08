"""`python -m bfc.export policy.pt policy.onnx`: export a policy file for deployment.

The export itself lives with the policy contract (bfc.agent.onnx: `export_onnx`, `OnnxController`,
`read_metadata`); this module is the command line and the public names users import
(`from bfc.export import export_onnx, OnnxController`). See docs/export.md.

Exit status 2, with one `error: ...` line, on a missing or invalid policy file, an unwritable
output path or a missing extra.
"""

from __future__ import annotations

import argparse
import sys

from bfc.agent.onnx import OnnxController, export_onnx, read_metadata

__all__ = ["OnnxController", "export_onnx", "main", "read_metadata"]


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bfc.export",
        description="Export a bfc policy file (policy.pt) to ONNX: the deterministic policy with the "
        "observation and action maps inside (docs/export.md).",
    )
    parser.add_argument("policy", help="policy.pt written by train.py (e.g. pretrained/policy.pt)")
    parser.add_argument("output", help="the .onnx file to write")
    parser.add_argument("--opset", type=int, default=None, help="ONNX opset (default: the exporter's, 20)")
    args = parser.parse_args(argv)
    try:
        path = export_onnx(args.policy, args.output, opset=args.opset)
    except (FileNotFoundError, ValueError, ImportError, OSError) as err:
        message = str(err).splitlines()[0] if str(err) else type(err).__name__
        message = message if len(message) <= 300 else message[:297] + "..."
        print(f"error: {message}", file=sys.stderr)
        return 2
    settings = read_metadata(path)
    print(
        f"wrote {path} ({settings['action_map']} map, fly at {settings['control_hz']:g} Hz, "
        f"hover {settings['hover_speed']:.1f} rad/s, max {settings['max_rotor_speed']:g} rad/s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
