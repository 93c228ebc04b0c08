"""One training run (or a sweep) on a real single-node Ray cluster, started here on 127.0.0.1 in a
network namespace of its own (`unshare --net`: Ray otherwise advertises the machine's network
address) and stopped at the end; prints each job's training frames/s and time to 0.905.

    python bench/ray_cluster.py [--port 6391] [--cpus 2] [-- train.py overrides]

Needs the `ray` extra and util-linux's `unshare` (root, or unprivileged user namespaces).
The jobs go through Hydra's Ray launcher (`hydra/launcher=ray hydra.launcher.ray.init.address=
127.0.0.1:<port>`), as docs/training.md, "Sweeps on a Ray cluster", runs them on a real cluster.
"""

from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = """
set -e
ip link set lo up
ray start --head --port={port} --num-cpus={cpus} --include-dashboard=false --disable-usage-stats > {out}/ray.log 2>&1
trap 'ray stop --force > /dev/null 2>&1' EXIT
{python} train.py -m hydra/launcher=ray hydra.launcher.ray.init.address=127.0.0.1:{port} {overrides} \\
  hydra.sweep.dir={out}/sweep > {out}/sweep.out 2> {out}/sweep.err
"""


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--port", type=int, default=6391)
    p.add_argument("--cpus", type=int, default=2)
    p.add_argument("overrides", nargs="*", help="train.py overrides (a sweep too: seed=0,1)")
    args = p.parse_args()
    net = ["unshare", "--net"] if os.geteuid() == 0 else ["unshare", "--map-root-user", "--net"]
    with tempfile.TemporaryDirectory() as out:
        overrides = " ".join(shlex.quote(o) for o in ["logger.progress=false", *args.overrides])
        script = SCRIPT.format(port=args.port, cpus=args.cpus, out=out, python=sys.executable, overrides=overrides)
        env = {**os.environ, "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}"}
        r = subprocess.run([*net, "bash", "-c", script], cwd=ROOT, env=env)
        if r.returncode != 0:
            sys.exit(Path(out, "sweep.err").read_text()[-3000:] if Path(out, "sweep.err").exists() else "failed")
        print(f"# Ray cluster on 127.0.0.1:{args.port}, {args.cpus} CPUs; overrides: {' '.join(args.overrides)}")
        for summary_path in sorted(Path(out, "sweep").rglob("summary.json")):
            s = json.loads(summary_path.read_text())
            reached = s["first_reached_0.905"]
            when = (
                f"{reached['frames'] / 1e6:.2f}M frames, {reached['wall_seconds']:.0f} s of training"
                if reached
                else "never"
            )
            job = summary_path.parent.relative_to(Path(out, "sweep"))
            print(f"{job}: {s['frames'] / s['wall_seconds']:,.0f} frames/s overall; 0.905 at {when}")


if __name__ == "__main__":
    main()
