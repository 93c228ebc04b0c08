"""Write docs/report/paper_regime/ from the runs of bench/paper_regime.sh: the paper's regime's
Table 2 beside the paper's and bfc's, its learning curves and the claims table
(bfc.evaluation.regime). Every run's final policy flies the test starts (a few minutes).

    python bench/paper_regime_report.py [--out docs/report/paper_regime] [--starts 100]

First every finished run under the sweeps (multirun/paper_regime*) is kept in the repository,
under `--out`/runs/ (its summary and validation curve, config, final policy and episode returns:
under 1 MB a run); the report is then written from the kept runs alone, so a fresh clone rebuilds
it without the sweeps' folders. Paused runs stay in the sweeps, where their checkpoints go on.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bfc.config import TestProtocolConfig  # noqa: E402
from bfc.evaluation.regime import keep_finished_runs, write_regime_report  # noqa: E402

COMMAND = "python bench/paper_regime_report.py"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweeps", nargs="+", default=[f"multirun/paper_regime{s}" for s in ("", "_nojd", "_algos")])
    parser.add_argument("--out", default="docs/report/paper_regime")
    parser.add_argument("--starts", type=int, default=100, help="test starts per set")
    args = parser.parse_args()
    os.chdir(ROOT)  # the report names its runs relative to the repository
    kept = Path(args.out) / "runs"
    for run in keep_finished_runs([Path(s) for s in args.sweeps if Path(s).is_dir()], kept):
        print(f"kept {run}")
    if not kept.is_dir():
        where = ", ".join([str(kept), *args.sweeps])
        sys.exit(f"error: no finished run in {where}: run `bash bench/paper_regime.sh` first")
    header = (
        f"Runs: `{kept}` (each finished run of `bash bench/paper_regime.sh`, kept by this command). "
        f"Command: `{COMMAND}`. Every final policy is flown again each time the report is built: the figures "
        "repeat on one machine, and on another CPU a policy that barely flies can end a few starts differently "
        '(docs/training.md, "The test figures depend on the CPU").'
    )
    path = write_regime_report(
        [kept],
        args.out,
        bfc_table2="docs/report/table2/table2.json",
        bfc_algos="docs/report/algos/table2.json",
        protocol=TestProtocolConfig(num_starts=args.starts),
        header=header,
    )
    print(path)


if __name__ == "__main__":
    main()
