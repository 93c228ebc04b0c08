#!/usr/bin/env bash
# A real single-node SLURM cluster on localhost (Debian's slurm-wlm and munge), started here by
# hand, without systemd or cgroups, with every file under a temporary directory; Hydra's
# submitit_slurm launcher runs a tiny two-job sweep on it, then (unless --no-requeue) a sweep of two
# longer jobs, one preempted by SIGUSR2 (submitit's checkpoint hook requeues it) and one requeued
# by `scontrol requeue`: both must resume from their checkpoints. Prints the jobs' outcome and
# the wall-clock; stops every daemon it started. docs/training.md, "SLURM through submitit".
#
#   bench/slurm_cluster.sh [--no-requeue] [--keep] [-- more train.py overrides]
#
# Debian or Ubuntu, as root (apt-get installs slurm-wlm and munge if missing; slurmd runs jobs as
# root); the `submitit` extra (pip install -e ".[submitit]"). PYTHON (default .venv/bin/python),
# BFC_SLURM_PORT (slurmctld's port, default 6917; slurmd takes the next one) and
# BFC_SLURM_FRAMES (each requeued job's frames, default 65536) change the defaults.
# --keep leaves the temporary directory (logs, slurm.conf, the sweeps) in place.
set -uo pipefail

ROOT=$(cd "$(dirname "$0")/.." && pwd)
PYTHON=${PYTHON:-$ROOT/.venv/bin/python}
PORT=${BFC_SLURM_PORT:-6917}
FRAMES=${BFC_SLURM_FRAMES:-65536}
REQUEUE=1
KEEP=0
EXTRA=()
while [ $# -gt 0 ]; do
  case "$1" in
    --no-requeue) REQUEUE=0 ;;
    --keep) KEEP=1 ;;
    --) shift; EXTRA=("$@"); break ;;
    -h | --help) sed -n '2,15p' "$0" | sed 's/^# \{0,1\}//'; exit 0 ;;
    *) echo "error: unknown option '$1' (allowed: --no-requeue, --keep, -- train.py overrides)" >&2; exit 2 ;;
  esac
  shift
done

fail() { echo "error: $*" >&2; exit 2; }
[ "$(id -u)" -eq 0 ] || fail "needs root (it installs slurm-wlm and munge, and slurmd runs the jobs as root)"
if ! command -v slurmctld > /dev/null || ! command -v slurmd > /dev/null || ! command -v munged > /dev/null; then
  command -v apt-get > /dev/null || fail "slurm-wlm and munge are not installed and there is no apt-get to install them"
  DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends slurm-wlm munge > /dev/null \
    || fail "apt-get install slurm-wlm munge failed (run apt-get update first?)"
fi
"$PYTHON" -c "import hydra_plugins.hydra_submitit_launcher" 2> /dev/null \
  || fail "the submitit launcher is not installed for $PYTHON: pip install -e \".[submitit]\""

# tiny jobs, as tests/test_sweeps.py's TINY: one thread each, collected in the learner's process
TINY=(env.num_envs=16 collector.frames_per_batch=512 collector.total_frames=1024 collector.workers=0
  loss.num_minibatches=2 eval.num_starts=2 eval.seconds=0.5 eval.hold_seconds=0.2 eval.interval_frames=512
  checkpoint.interval_frames=512 logger.progress=false env.num_threads=1 torch_threads=1)
LAUNCHER=(hydra/launcher=submitit_slurm hydra.launcher.partition=bfc hydra.launcher.timeout_min=10
  hydra.launcher.cpus_per_task=1)

T=$(mktemp -d /tmp/bfc-slurm.XXXXXX)
chmod 755 "$T"  # munged wants every directory above its socket searchable by all
mkdir -p "$T/munge" "$T/run" "$T/state" "$T/spool" "$T/log"
chmod 700 "$T/munge"
export SLURM_CONF=$T/slurm.conf

stop() {
  local name pid
  for name in slurmd slurmctld; do
    pid=$(cat "$T/run/$name.pid" 2> /dev/null) || continue
    kill "$pid" 2> /dev/null
    for _ in $(seq 50); do kill -0 "$pid" 2> /dev/null || break; sleep 0.1; done
    kill -9 "$pid" 2> /dev/null
  done
  [ -S "$T/run/munge.sock" ] && munged --stop --socket="$T/run/munge.sock" > /dev/null 2>&1
  if [ "$KEEP" = 1 ]; then echo "# kept $T"; else rm -rf "$T"; fi
}
trap stop EXIT
trap 'exit 130' INT TERM

# munge: a key and a socket of its own, so that a munged already running here is left alone
dd if=/dev/urandom of="$T/munge/munge.key" bs=1024 count=1 status=none
chmod 400 "$T/munge/munge.key"
munged --socket="$T/run/munge.sock" --key-file="$T/munge/munge.key" --pid-file="$T/run/munged.pid" \
  --log-file="$T/log/munged.log" --seed-file="$T/munge/munged.seed" \
  || fail "munged did not start: $(tail -1 "$T/log/munged.log")"

MEM_MB=$(awk '/MemTotal/ {print int($2 / 1024 * 0.9)}' /proc/meminfo)
cat > "$SLURM_CONF" << EOF
# one node on localhost; no systemd, no cgroups (proctrack/linuxproc, task/none), no accounting
# database (jobcomp/filetxt keeps a line per finished job instead); a requeued job waits
# cred_expire seconds (120 by default), then for a scheduling pass (sched_interval: 60 s by
# default): 10 s and 2 s here
ClusterName=bfc
SlurmctldHost=localhost
SlurmctldPort=$PORT
SlurmdPort=$((PORT + 1))
SlurmUser=root
SlurmdUser=root
AuthType=auth/munge
AuthInfo=socket=$T/run/munge.sock,cred_expire=10
CredType=cred/munge
StateSaveLocation=$T/state
SlurmdSpoolDir=$T/spool
SlurmctldPidFile=$T/run/slurmctld.pid
SlurmdPidFile=$T/run/slurmd.pid
SlurmctldLogFile=$T/log/slurmctld.log
SlurmdLogFile=$T/log/slurmd.log
MailProg=/bin/true
ProctrackType=proctrack/linuxproc
TaskPlugin=task/none
JobAcctGatherType=jobacct_gather/none
AccountingStorageType=accounting_storage/none
JobCompType=jobcomp/filetxt
JobCompLoc=$T/log/jobcomp.txt
SchedulerType=sched/backfill
SchedulerParameters=bf_interval=1,sched_interval=2
SelectType=select/cons_tres
SelectTypeParameters=CR_Core
MpiDefault=none
ReturnToService=2
KillWait=5
NodeName=localhost CPUs=$(nproc) RealMemory=$MEM_MB State=UNKNOWN
PartitionName=bfc Nodes=localhost Default=YES MaxTime=INFINITE State=UP
EOF

slurmctld || fail "slurmctld did not start: $(tail -3 "$T/log/slurmctld.log" 2> /dev/null)"
slurmd -N localhost || fail "slurmd did not start: $(tail -3 "$T/log/slurmd.log" 2> /dev/null)"
for _ in $(seq 60); do
  [ "$(sinfo -h -n localhost -o %t 2> /dev/null)" = idle ] && break
  sleep 1
done
[ "$(sinfo -h -n localhost -o %t 2> /dev/null)" = idle ] \
  || fail "the node never became idle: $(sinfo 2>&1 | tail -1); $(tail -2 "$T/log/slurmd.log")"
echo "# $(sinfo -V) on localhost, $(nproc) CPUs; partition bfc; $T"
sinfo

now() { date +%s.%N; }
seconds() { awk -v a="$1" -v b="$2" 'BEGIN {printf "%.1f", b - a}'; }

# check SWEEP_DIR JOBS FRAMES [resumed]: JOBS jobs, each finished with FRAMES frames (and resumed, if asked)
check() {
  "$PYTHON" - "$@" << 'EOF'
import json, sys
from pathlib import Path
sweep, count, frames, resumed = Path(sys.argv[1]), int(sys.argv[2]), int(sys.argv[3]), len(sys.argv) > 4
jobs = json.loads((sweep / "sweep.json").read_text())
bad = []
for job in jobs:
    run = Path(job["run_dir"])
    summary = json.loads((run / "summary.json").read_text()) if (run / "summary.json").is_file() else {}
    ok = (job["status"] == "finished" and (run / "policy.pt").is_file() and summary.get("frames") == frames
          and (not resumed or summary.get("resumed_from")))
    print(f"  {run.relative_to(sweep)}: {job['status']}, policy.pt {(run / 'policy.pt').is_file()}, "
          f"frames {summary.get('frames')}, resumed_from {summary.get('resumed_from')}")
    bad += [] if ok else [str(run)]
sys.exit(f"error: not as expected: {bad}" if bad or len(jobs) != count else 0)
EOF
}

# the jobs' outcome as SLURM saw them (no accounting database here: sacct would say "Slurm
# accounting storage is disabled"; jobcomp/filetxt has one line per job that ended)
outcome() {
  echo "  squeue: $(squeue -h | wc -l) jobs queued or running"
  awk -v from="$1" '{
      split($1, id, "="); if (id[2] + 0 < from) next
      line = "  "
      for (i = 1; i <= NF; i++) if ($i ~ /^(JobId|JobState|StartTime|EndTime|ArrayJobId|ArrayTaskId|ExitCode)=/) line = line " " $i
      print line
    }' "$T/log/jobcomp.txt"
}

STATUS=0
SWEEP=$T/sweep
echo "# 1. a sweep of two tiny jobs (+ablation=jd,ppo)"
echo "python train.py -m ${LAUNCHER[*]} +ablation=jd,ppo ${TINY[*]} hydra.sweep.dir=$SWEEP ${EXTRA[*]}"
start=$(now)
(cd "$ROOT" && "$PYTHON" train.py -m "${LAUNCHER[@]}" +ablation=jd,ppo "${TINY[@]}" "hydra.sweep.dir=$SWEEP" \
  "${EXTRA[@]}" > "$T/sweep.out" 2> "$T/sweep.err")
rc=$?
echo "  exit status $rc, $(seconds "$start" "$(now)") s wall-clock (submission to the sweep's report)"
check "$SWEEP" 2 1024 || { STATUS=1; tail -20 "$T/sweep.err"; }
outcome 0

# wait_checkpoint SWEEP RUN_DIR_GLOB ARRAY_INDEX: once the run has a checkpoint, its SLURM id (array_task)
wait_checkpoint() {
  for _ in $(seq 600); do
    if compgen -G "$1/$2/checkpoints/last.pt" > /dev/null; then
      # an array's job i has the folder <array id>_<i>; a sweep of one job is no array: <job id>
      compgen -G "$1/.submitit/*_$3/*_submitted.pkl" || compgen -G "$1/.submitit/*/*_submitted.pkl"
      return 0
    fi
    sleep 0.2
  done
  return 1
}

# interrupted NAME SEEDS ACTIONS LAUNCHER_OVERRIDES...: a sweep of $FRAMES-frame jobs; ACTIONS[i]
# (usr2: what SLURM sends before a time limit or a preemption; requeue: scontrol requeue) hits job
# i once it has a checkpoint; every job must end at $FRAMES frames, resumed from its checkpoint
interrupted() {
  local name=$1 seeds=$2 actions=$3 dir=$T/$1 i=0 action id ids=() rc start last
  shift 3
  echo "python train.py -m $* seed=$seeds ${TINY[*]} collector.total_frames=$FRAMES hydra.sweep.dir=$dir"
  last=$(awk -F'[ =]' '{print $2}' "$T/log/jobcomp.txt" | sort -n | tail -1)
  start=$(now)
  (cd "$ROOT" && exec "$PYTHON" train.py -m "$@" "seed=$seeds" "${TINY[@]}" "collector.total_frames=$FRAMES" \
    "hydra.sweep.dir=$dir" "${EXTRA[@]}" > "$T/$name.out" 2> "$T/$name.err") &
  local sweep_pid=$!
  for action in $actions; do
    if id=$(wait_checkpoint "$dir" "*/seed*_$i" "$i" | head -1 | xargs -r dirname | xargs -r basename) && [ -n "$id" ]; then
      ids+=("$id")
      case $action in
        usr2) scancel --signal=USR2 "$id" && echo "  SIGUSR2 to job $id (scancel --signal=USR2 $id)" ;;
        requeue) scontrol requeue "$id" && echo "  scontrol requeue $id" ;;
      esac
    else
      echo "  job $i never checkpointed"
    fi
    i=$((i + 1))
  done
  wait "$sweep_pid"
  rc=$?
  echo "  exit status $rc, $(seconds "$start" "$(now)") s wall-clock (submission to the sweep's report)"
  check "$dir" "${#ids[@]}" "$FRAMES" resumed || { STATUS=1; tail -20 "$T/$name.err"; }
  for _ in $(seq 30); do [ -z "$(squeue -h)" ] && break; sleep 1; done
  for id in "${ids[@]}"; do
    echo "  $id: $(scontrol show job -o "$id" 2> /dev/null | grep -o 'JobState=[A-Z]* \|Restarts=[0-9]*' | tr -d '\n')"
  done
  grep -h "Caught signal\|Requeued job\|Job not requeued" "$dir"/.submitit/*/*_log.out 2> /dev/null \
    | grep -v '^\[' | sed 's/^submitit [A-Z]* ([0-9-]* /  /' | cut -c1-140
  outcome $((last + 1))
}

if [ "$REQUEUE" = 1 ]; then
  echo "# 2. preempted: two jobs of $FRAMES frames, job 0 gets SIGUSR2, job 1 'scontrol requeue'"
  interrupted preempted 0,1 "usr2 requeue" "${LAUNCHER[@]/timeout_min=10/timeout_min=20}"
  echo "# 3. at the time limit: one job of $FRAMES frames gets SIGUSR2 with timeout_min=10"
  interrupted timelimit 0 "usr2" "${LAUNCHER[@]}" hydra.launcher.max_num_timeout=1
fi
exit $STATUS
