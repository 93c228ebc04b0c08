#!/usr/bin/env bash
# The paper's regime (docs/report/paper_regime/): +preset=paper's BFC (JD-CSS-TDTS), plain PPO,
# JD, JD-CSS and JD-TDTS for seeds 0, 1, 2; CSS, TDTS and CSS-TDTS for seed 0; and the paper's
# algorithm comparison (+preset=paper_trpo, paper_ddpg: plain and enhanced, seed 0). Each run is on
# a 20M-frame schedule (JD's decay and the learning rate's anneal end at 20M frames).
#
#   bash bench/paper_regime.sh                 # every job to 20M frames (about 2 h a job here)
#   PAUSE=2000000 bash bench/paper_regime.sh   # every job to 2M frames, then paused; run again
#                                              # with a larger PAUSE (or none) to go on
#
# A job that is killed, paused or interrupted resumes from its checkpoint when the same command
# runs again (Hydra's job numbers, and so the run directories, depend on the lists below: keep
# them). Then: python bench/paper_regime_report.py
set -euo pipefail
cd "$(dirname "$0")/.."
PY=${PYTHON:-.venv/bin/python}
PAUSE=${PAUSE:-null}
common=(collector.total_frames=20000000 collector.workers=0 checkpoint.interval_frames=500000
        checkpoint.pause_at_frames="$PAUSE" logger.progress=false)
status=0
"$PY" train.py -m seed=0,1,2 +ablation=jd_css_tdts,ppo,jd,jd_css,jd_tdts +preset=paper "${common[@]}" \
  hydra.sweep.dir=multirun/paper_regime || status=$?
"$PY" train.py -m seed=0 +ablation=css,tdts,css_tdts +preset=paper "${common[@]}" \
  hydra.sweep.dir=multirun/paper_regime_nojd || status=$?
"$PY" train.py -m seed=0 +preset=paper_trpo,paper_ddpg +ablation=jd_css_tdts,ppo "${common[@]}" \
  hydra.sweep.dir=multirun/paper_regime_algos || status=$?
exit $status
