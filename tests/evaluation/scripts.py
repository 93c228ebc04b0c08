"""The entry points as a user runs them, in a new interpreter (shared by the evaluation tests)."""

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
SHIPPED = ROOT / "pretrained" / "policy.pt"


def run_script(script: str, *args, out, env=None, timeout: int = 300):
    """`python <script> args... hydra.run.dir=<out>` from the repository root."""
    return subprocess.run(
        [sys.executable, script, *args, f"hydra.run.dir={out}"],
        cwd=ROOT,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
    )


def evaluate(*args, out, env=None):
    return run_script("evaluate.py", *args, out=out, env=env)
