"""Train BFC (PPO + JD/CSS/TDTS) on the MuJoCo Hummingbird.

python train.py                                  # the full BFC (JD-CSS-TDTS) + bfc's robust extras
python train.py extras=none                      # the paper's BFC alone
python train.py +preset=paper                    # the paper as written (+preset=paper_trpo, paper_ddpg)
python train.py +ablation=jd_tdts seed=1         # one ablation variant
python train.py -m +ablation=ppo,jd,jd_css_tdts seed=0,1,2   # a sweep
python train.py resume=outputs/2026-11-22/10-00-00           # continue a killed run

Bad input (an unknown key, a value out of range, a run directory with nothing to resume) ends
with a one-line `error: ...` on stderr and exit status 2. SIGTERM (a scheduler's preemption) writes
a checkpoint and exits with status 143; a collector worker that dies ends the run with one
`error:` line and status 1; Ctrl-C exits with status 130 (bfc.lifetime, docs/training.md).
"""

from bfc.imports import hold_garbage_collection, release_garbage_collection

if __name__ == "__main__":
    hold_garbage_collection()  # while everything imports; main() releases it once training's imports are done

import os
import sys
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import OmegaConf

import bfc.headless_gl  # noqa: F401  (before mujoco is imported: MUJOCO_GL=egl without a display, logger.video)
from bfc import lifetime
from bfc.cli import fail, precheck, with_launcher_defaults
from bfc.config import check_keys, validate  # importing bfc.config registers the schema Hydra composes with
from bfc.sweeps import objective, write_status

# What a resume may change from the command line (everything else is the run's own config)
RESUME_OVERRIDES = ("checkpoint.pause_at_frames",)


def resume_config(cfg):
    """The config a killed run started with (it goes on with that, but for RESUME_OVERRIDES given
    on the command line: a paused run goes on to a new pause), and its directory."""
    run_dir = Path(cfg.resume)
    if not any((run_dir / "checkpoints" / name).is_file() for name in ("last.pt", "previous.pt")):
        raise FileNotFoundError(f"resume={cfg.resume}: no checkpoints/last.pt there to resume from")
    if not (run_dir / "config.yaml").is_file():
        raise FileNotFoundError(f"resume={cfg.resume}: no config.yaml there (not a bfc run directory)")
    saved = OmegaConf.load(run_dir / "config.yaml")
    try:
        check_keys(saved)
    except ValueError as err:
        raise ValueError(f"resume={cfg.resume}: its config.yaml is from another bfc version ({err})") from None
    merged = OmegaConf.merge(cfg, saved, {"resume": str(run_dir)})
    given = {o.split("=", 1)[0].lstrip("+") for o in HydraConfig.get().overrides.task}
    for key in RESUME_OVERRIDES:
        if key in given:
            OmegaConf.update(merged, key, OmegaConf.select(cfg, key))
    return merged, run_dir


@hydra.main(config_path="conf", config_name="config", version_base="1.3")
def main(cfg) -> float:
    """One training run; in a sweep, one job: its outcome goes to its run directory's
    status.json, and a job that fails is reported (one line) while the others go on."""
    multirun = HydraConfig.get().mode == RunMode.MULTIRUN
    run_dir = Path(HydraConfig.get().runtime.output_dir)
    try:
        if cfg.resume:
            cfg, run_dir = resume_config(cfg)
        validate(cfg)
        # torch, TorchRL and MuJoCo load only for a config that passed its checks: bad input fails at once
        from bfc.training import train

        release_garbage_collection()  # the imports are done; before the collector's worker forks
        if multirun:
            lifetime.bind_job_to_sweep()  # a launcher's worker process ends with the sweep
            write_status(run_dir, "running", pid=os.getpid())
        summary = train(cfg, run_dir)
    except KeyboardInterrupt:
        if multirun:
            write_status(run_dir, "interrupted")
        raise
    except lifetime.Preempted as p:
        if multirun:
            write_status(run_dir, "preempted", frames=p.frames)
        again = "the same command" if multirun else f"python train.py resume={run_dir}"
        print(f"preempted (SIGTERM): checkpoint written at {p.frames} frames; resume with: {again}", file=sys.stderr)
        sys.exit(lifetime.PREEMPTED)
    except Exception as err:
        if not multirun:
            if isinstance(err, (ValueError, FileNotFoundError)):
                fail(err)
            if isinstance(err, lifetime.WorkerDied):
                fail(err, status=lifetime.FAILED)
            raise
        line = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
        write_status(run_dir, "failed", error=line)
        print(f"error: job {run_dir}: {line}", file=sys.stderr)
        return float("nan")
    value = objective(summary, cfg.sweep_objective)
    if multirun:
        if summary.get("paused"):
            write_status(run_dir, "paused", frames=summary["frames"])
        else:
            write_status(run_dir, "finished", objective=value)
    print(f"run directory: {run_dir}")
    print(
        f"frames {summary['frames']}, wall-clock {summary['wall_seconds']} s, "
        f"final success {summary['final_success_rate']}, best {summary['best_success_rate']}"
    )
    return value


if __name__ == "__main__":
    sys.argv[1:] = with_launcher_defaults(precheck("config"))
    lifetime.mark_sweep_process()
    try:
        main()
    except KeyboardInterrupt:
        print("interrupted: every finished run is complete; run the same command again to resume", file=sys.stderr)
        sys.exit(lifetime.INTERRUPTED)
