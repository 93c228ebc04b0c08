"""Start-up: how long `python train.py` takes before its first training frame, and how much of
it is bfc's own (everything after `import torch, torchrl, mujoco`).

    python bench/startup.py [--rounds 3] [-- train.py overrides]

Each round launches `python train.py collector.total_frames=<one batch> ...` as a user does and
reads `collecting_since_unix_seconds` from its summary.json: the launch. Then a second launch
first times `import torch, torchrl, mujoco` in its own process and runs train.py after it:
bfc's share is the rest of that launch (so the libraries' own spread, which is large on a shared
machine, stays out of it). Prints the medians, and which
heavy optional packages (plotting, SciPy, OSQP, ONNX, Ray, pandas, boto3) a training process
imported (it should import none).
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
# a training process imports none of these
HEAVY = ("matplotlib", "scipy", "osqp", "onnx", "onnxruntime", "ray", "pandas", "boto3")
PROBE = (
    "import time; t = time.perf_counter(); import torch, torchrl, mujoco; libraries = time.perf_counter() - t\n"
    "import runpy, sys; sys.argv = ['train.py', *sys.argv[1:]];\n"
    "try:\n    runpy.run_path('train.py', run_name='__main__')\nexcept SystemExit:\n    pass\n"
    "print('LIBRARIES', libraries)\n"
    f"print('LOADED', [m for m in {HEAVY!r} if m in sys.modules])"
)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("overrides", nargs="*", help="train.py overrides")
    args = p.parse_args()
    launch, probed, libraries = [], [], []
    for _ in range(args.rounds):
        for command, times in (([sys.executable, "train.py"], launch), ([sys.executable, "-c", PROBE], probed)):
            with tempfile.TemporaryDirectory() as run_dir:
                overrides = ["logger.progress=false", f"hydra.run.dir={run_dir}", "eval.num_starts=1", *args.overrides]
                batch = ["collector.total_frames=1"]  # rounded up to one batch
                t = time.time()
                r = subprocess.run([*command, *batch, *overrides], cwd=ROOT, capture_output=True, text=True)
                if r.returncode != 0:
                    sys.exit(r.stderr[-2000:])
                summary = json.loads((Path(run_dir) / "summary.json").read_text())
                times.append(summary["collecting_since_unix_seconds"] - t)
        *_, lib, loaded = r.stdout.strip().splitlines()
        libraries.append(float(lib.removeprefix("LIBRARIES ")))
    rests = [total - lib for total, lib in zip(probed, libraries, strict=True)]
    rest = statistics.median(rests)
    print(f"launch to the first training frame: {statistics.median(launch):.2f} s (median of {args.rounds})")
    print(f"  import torch, torchrl, mujoco, first in a launch: {statistics.median(libraries):.2f} s")
    print(f"  the rest (Python start-up, bfc, Hydra, the envs, the networks): {rest:.2f} s (least {min(rests):.2f} s)")
    print(f"  heavy optional packages the training process imported: {loaded.removeprefix('LOADED ')}")


if __name__ == "__main__":
    main()
