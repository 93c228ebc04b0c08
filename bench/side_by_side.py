"""One bench script on two commits, in one sitting on one machine, alternating: the before and
after figures a change is judged by (machines and hours differ; the ratio is what counts).

    python bench/side_by_side.py --before 61d8adc [--after HEAD] [--rounds 2] -- update_time.py --threads 1

Each commit is checked out once into a temporary git worktree (its own bench/ and bfc/, the
repository's .venv); the script then runs there `--rounds` times, before and after in turn,
and each run's output is printed under a header naming the commit. A script the before commit
does not have yet is taken from the after commit (it runs in, and imports, the before tree), as
the script is on both with `--after-script` (a benchmark that measures better than it did).
"""

from __future__ import annotations

import argparse
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def worktree(rev: str, parent: Path) -> Path:
    path = parent / rev.replace("/", "_")
    add = ["git", "worktree", "add", "--detach", "-f", str(path), rev]
    subprocess.run(add, cwd=ROOT, check=True, capture_output=True)
    return path


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--before", required=True, help="the commit before the change")
    p.add_argument("--after", default="HEAD", help="the commit after it (default HEAD)")
    p.add_argument("--rounds", type=int, default=1)
    p.add_argument("--after-script", action="store_true", help="run the after commit's script on both trees")
    p.add_argument("script", help="a script of bench/, e.g. update_time.py")
    p.add_argument("args", nargs=argparse.REMAINDER, help="its arguments")
    args = p.parse_args()
    with tempfile.TemporaryDirectory(prefix="bfc-side-by-side-") as tmp:
        trees = {rev: worktree(rev, Path(tmp)) for rev in (args.before, args.after)}
        try:
            for round_ in range(args.rounds):
                for rev, tree in trees.items():
                    short = ["git", "rev-parse", "--short", "HEAD"]
                    head = subprocess.run(short, cwd=tree, text=True, capture_output=True)
                    print(f"\n## {rev} ({head.stdout.strip()}), round {round_ + 1}", flush=True)
                    script = tree / "bench" / args.script
                    if tree != trees[args.after] and (args.after_script or not script.exists()):
                        # the after tree's script, put in this tree (its paths resolve to this one)
                        shutil.copyfile(trees[args.after] / "bench" / args.script, script)
                    command = [sys.executable, str(script), *args.args]
                    subprocess.run(command, cwd=tree, env={**os.environ, "PYTHONPATH": str(tree)}, check=True)
        finally:
            for tree in trees.values():
                subprocess.run(["git", "worktree", "remove", "--force", str(tree)], cwd=ROOT, capture_output=True)


if __name__ == "__main__":
    main()
