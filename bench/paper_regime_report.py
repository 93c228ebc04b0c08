"""Write docs/report/paper_regime/ from the sweep of bench/paper_regime.sh: the paper's regime's
Table 2 beside the paper's and bfc's, its learning curves and the claims table
(bfc.evaluation.regime). Every run's final policy flies the test starts (a few minutes).

    python bench/paper_regime_report.py [--out docs/report/paper_regime] [--starts 100]
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bfc.config import TestProtocolConfig  # noqa: E402
from bfc.evaluation.regime import write_regime_report  # noqa: E402

COMMAND = "python bench/paper_regime_report.py"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sweeps", nargs="+", default=[f"multirun/paper_regime{s}" for s in ("", "_nojd", "_algos")])
    parser.add_argument("--out", default="docs/report/paper_regime")
    parser.add_argument("--starts", type=int, default=100, help="test starts per set")
    args = parser.parse_args()
    os.chdir(ROOT)  # the report names its sweeps relative to the repository
    sweeps = [Path(s) for s in args.sweeps if Path(s).is_dir()]
    if not sweeps:
        sys.exit(f"error: none of {', '.join(args.sweeps)} exists: run `bash bench/paper_regime.sh` first")
    header = (
        f"Sweeps: {', '.join(f'`{s}`' for s in sweeps)}, trained by `bash bench/paper_regime.sh`. Command: `{COMMAND}`."
    )
    path = write_regime_report(
        sweeps,
        args.out,
        bfc_table2="docs/report/table2/table2.json",
        bfc_algos="docs/report/algos/table2.json",
        protocol=TestProtocolConfig(num_starts=args.starts),
        header=header,
    )
    print(path)


if __name__ == "__main__":
    main()
