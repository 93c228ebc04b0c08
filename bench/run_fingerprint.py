"""The fingerprint of a training run: a hash of its final weights, optimizer state and RNG state,
and its evaluations. A change that must leave runs unchanged prints the same lines before and
after (the weights after a run hold every batch it learned from):

    python bench/side_by_side.py --before REV -- run_fingerprint.py seed=0 collector.total_frames=1000000

Arguments are `train.py` overrides; the run goes to a temporary folder (left nowhere). It runs the
`train.py` of the working directory (side_by_side.py runs it in each commit's tree).
"""

from __future__ import annotations

import argparse
import hashlib
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import torch


def digest(value) -> str:
    """SHA-256 (first 16 hex digits) of every tensor in a nested checkpoint entry, in key order."""
    h = hashlib.sha256()

    def walk(v):
        if isinstance(v, torch.Tensor):
            h.update(v.detach().reshape(-1).contiguous().view(torch.uint8).numpy().tobytes())
        elif isinstance(v, dict):
            for k in sorted(v, key=str):
                h.update(str(k).encode())
                walk(v[k])
        elif isinstance(v, (list, tuple)):
            for x in v:
                walk(x)
        else:
            h.update(repr(v).encode())

    walk(value)
    return h.hexdigest()[:16]


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("overrides", nargs="*", help="train.py overrides, e.g. seed=0 collector.total_frames=1000000")
    overrides = p.parse_args().overrides
    with tempfile.TemporaryDirectory(prefix="bfc-fingerprint-") as tmp:
        command = [sys.executable, "train.py", *overrides, "logger.progress=false", f"hydra.run.dir={tmp}"]
        subprocess.run(command, check=True, capture_output=True)
        ckpt = torch.load(Path(tmp) / "checkpoints" / "last.pt", weights_only=False)
        summary = json.loads((Path(tmp) / "summary.json").read_text())
    print(f"# train.py {' '.join(overrides)}: {summary['frames']:,} frames")
    for part in ("actor", "critic", "optimizer", "collector", "torch_rng"):
        if part in ckpt:
            print(f"{part:10s} {digest(ckpt[part])}")
    print("evaluations", [round(h["eval/success_rate"], 4) for h in summary["history"]])


if __name__ == "__main__":
    main()
