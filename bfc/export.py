"""`python -m bfc.export policy.pt policy.onnx|policy.h|app_dir`: export a policy file for deployment.

The exports live with the policy contract: ONNX in bfc.agent.onnx (`export_onnx`, `OnnxController`,
`read_metadata`), C in bfc.agent.c_export (`export_c`: one self-contained C99 header) and
bfc.agent.c_controller (`CController`, which flies that header through ctypes), a Crazyflie
firmware app in bfc.agent.crazyflie_app (`export_crazyflie`, `CrazyflieAppController`). This module is
the command line and the public names users import
(`from bfc.export import export_onnx, export_c, OnnxController, CController`). See docs/export.md.

The format is `--format onnx|c|crazyflie`, or else the output's suffix (.onnx, .h; crazyflie
writes a folder and is always named). Exit status 2, with one
`error: ...` line, on a missing or invalid policy file, a policy the format cannot express, an
unwritable output path, a format the output name contradicts or does not tell, or a missing extra.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from bfc.agent import read_policy
from bfc.agent.c_controller import CController
from bfc.agent.c_export import export_c
from bfc.agent.crazyflie_app import CrazyflieAppController, export_crazyflie
from bfc.agent.onnx import OnnxController, export_onnx, read_metadata

__all__ = [
    "CController",
    "CrazyflieAppController",
    "OnnxController",
    "export_c",
    "export_crazyflie",
    "export_onnx",
    "main",
    "read_metadata",
]

FORMATS = {".onnx": "onnx", ".h": "c"}


def output_format(output, given: str | None) -> str:
    """The format to write: `given` (--format) or the one the output's suffix names; ValueError
    (one line) when the suffix names another format, or names none and no format is given."""
    suffix = Path(output).suffix.lower()
    implied = FORMATS.get(suffix)
    if given is None:
        if implied is None:
            raise ValueError(
                f"cannot tell the format from the output name {output!r}: "
                "name it *.onnx or *.h, or pass --format onnx|c"
            )
        return implied
    if implied is not None and implied != given:
        raise ValueError(f"--format {given} contradicts the output name {output!r} (a {suffix} file is {implied})")
    return given


def _fail(err: Exception) -> int:
    message = str(err).splitlines()[0] if str(err) else type(err).__name__
    message = message if len(message) <= 300 else message[:297] + "..."
    print(f"error: {message}", file=sys.stderr)
    return 2


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m bfc.export",
        description="Export a bfc policy file (policy.pt) for deployment: to ONNX (export_onnx), or to one "
        "self-contained C99 header (export_c); the deterministic policy with the observation and action maps "
        "inside (docs/export.md).",
    )
    parser.add_argument("policy", help="policy.pt written by train.py (e.g. pretrained/policy.pt)")
    parser.add_argument(
        "output", help="what to write: policy.onnx (ONNX), policy.h (C99 header) or a folder (--format crazyflie)"
    )
    parser.add_argument(
        "--format",
        choices=("onnx", "c", "crazyflie"),
        default=None,
        help="onnx, c, or crazyflie (a Crazyflie firmware app folder; default: from the output's suffix, "
        ".onnx -> onnx, .h -> c)",
    )
    parser.add_argument("--opset", type=int, default=None, help="ONNX opset (default: the exporter's, 20)")
    args = parser.parse_args(argv)
    try:
        fmt = output_format(args.output, args.format)
        if fmt != "onnx" and args.opset is not None:
            raise ValueError(f"--opset applies to the ONNX format only, not to --format {fmt}")
        if fmt == "crazyflie":
            path = export_crazyflie(args.policy, args.output)
        elif fmt == "c":
            path = export_c(args.policy, args.output)
        else:
            path = export_onnx(args.policy, args.output, opset=args.opset)
    except (FileNotFoundError, ValueError, ImportError, OSError) as err:
        return _fail(err)
    if fmt != "onnx":
        spec = read_policy(args.policy).spec
        settings = {
            "action_map": spec.action_map,
            "control_hz": spec.control_hz,
            "hover_speed": spec.nominal_airframe.hover_speed,
            "max_rotor_speed": spec.nominal_airframe.max_rotor_speed,
        }
    else:
        settings = read_metadata(path)
    print(
        f"wrote {path} ({settings['action_map']} map, fly at {settings['control_hz']:g} Hz, "
        f"hover {settings['hover_speed']:.1f} rad/s, max {settings['max_rotor_speed']:g} rad/s)"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
