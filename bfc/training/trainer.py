"""The training run: collect, update, evaluate on the paper's protocol, log, checkpoint, resume.

Everything a run writes goes under its run directory:
    tb/                  TensorBoard events (a resumed run appends here)
    config.yaml          the resolved config
    checkpoints/last.pt  the latest checkpoint (atomic: written to a temporary name, then renamed)
    policy.pt            the deployable policy: the best evaluation so far (highest success rate,
                         then lowest eval/position_error: the hover precision at the end of the
                         flights); checkpoint.keep_best=false: the latest evaluated policy
    policy_last.pt       the policy at the end of training
    summary.json         frames, wall-clock, success history, when 0.905 and 0.99 were first reached
"""

from __future__ import annotations

import json
import math
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf
from torchrl.record.loggers.tensorboard import TensorboardLogger

from bfc import keys
from bfc.collectors import carrier_state, episode_stats, make_collector, restore_carrier
from bfc.evaluation.fly import run_flights
from bfc.evaluation.metrics import tilt_degrees
from bfc.evaluation.protocol import inside_box, protocol_starts, success_and_time
from bfc.make_env import find_transform, make_env
from bfc.policy import atomic_save, save_policy
from bfc.training.ppo import make_loss, make_models, ppo_update
from bfc.transforms import ControlledStartingState, JumpingDistribution, PolicyObservation
from bfc.transforms._base import BatchedTransform

PAPER_SUCCESS = 0.905
CHECKPOINT = Path("checkpoints") / "last.pt"


class ProtocolEvaluator:
    """The paper's protocol inside training: fixed starts in the air, deterministic policy."""

    def __init__(self, cfg):
        e = cfg.eval
        eval_cfg = OmegaConf.merge(cfg, {"env": {"episode_seconds": e.seconds + 1.0}})
        self.env = make_env(eval_cfg, num_envs=e.num_starts, samplers=False, noise={"kind": "none"}, given_starts=True)
        self.env.set_seed(e.seed)
        self.starts = protocol_starts(e.num_starts, e.seed)
        dt = self.env.base_env.dt
        self.steps = round(e.seconds / dt)
        self.hold_steps = round(e.hold_seconds / dt)
        self.threshold, self.dt = e.threshold, dt

    def __call__(self, actor) -> dict[str, float]:
        flights = run_flights(self.env, actor, self.starts, self.steps)
        pos = flights.get(keys.POSITION)
        goal = flights.get(keys.GOAL)
        alive = flights.get("alive")
        inside = inside_box(pos, goal, self.threshold) & alive
        ok, _ = success_and_time(inside, self.hold_steps, self.dt)
        # Steady-state errors: the last 2 s of every flight that did not crash.
        tail = slice(-round(2.0 / self.dt), None)
        err = (pos - goal)[:, tail].norm(dim=-1)
        tilt = tilt_degrees(flights.get(keys.QUATERNION)[:, tail])
        survived = alive[:, -1]
        pick = survived if bool(survived.any()) else torch.ones_like(survived)
        return {
            "eval/success_rate": ok.float().mean().item(),
            "eval/position_error": err[pick].mean().item(),
            "eval/attitude_error": tilt[pick].mean().item(),
            "eval/crash_rate": 1.0 - survived.float().mean().item(),
        }


def _bfc_transforms(env):
    return [t for t in env.transform if isinstance(t, BatchedTransform)]


def _env_state(env) -> dict:
    base = env.base_env
    return {
        "physics": base._physics.clone(),
        "motor": base._motor.clone(),
        "lin_acc": base._lin_acc.clone(),
        "ang_acc": base._ang_acc.clone(),
        "steps": base._steps.clone(),
        "goal": base._goal.clone(),
        "generator": base._generator.get_state(),
        "physics_failures": base.physics_failures,
        "transforms": env.transform.state_dict(),
        "generators": [t.generator.get_state() for t in _bfc_transforms(env)],
    }


def _restore_env_state(env, state: dict) -> None:
    base = env.base_env
    for name in ("physics", "motor", "lin_acc", "ang_acc", "steps", "goal"):
        getattr(base, f"_{name}").copy_(state[name])
    base._generator.set_state(state["generator"])
    base.physics_failures = int(state["physics_failures"])
    env.transform.load_state_dict(state["transforms"])
    for t, g in zip(_bfc_transforms(env), state["generators"], strict=True):
        t.generator.set_state(g)


def css_figure(css: ControlledStartingState):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    grid = css.value_grid.numpy()
    r = css.xy_range
    fig, ax = plt.subplots(figsize=(4, 3.4))
    im = ax.imshow(grid, origin="lower", extent=(-r, r, -r, r), cmap="viridis")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("CSS square values (mean reward)")
    fig.colorbar(im, ax=ax)
    fig.tight_layout()
    return fig


def _hparams(cfg) -> dict:
    return {
        "variant": cfg.variant,
        "jd": cfg.jd.enabled,
        "css": cfg.css.enabled,
        "tdts": cfg.tdts.enabled,
        "seed": cfg.seed,
        "control_hz": cfg.env.control_hz,
        "num_envs": cfg.env.num_envs,
        "total_frames": cfg.collector.total_frames,
        "frames_per_batch": cfg.collector.frames_per_batch,
        "loss": cfg.loss.kind,
        "gamma": cfg.loss.gamma,
        "lmbda": cfg.loss.lmbda,
        "lr": cfg.optim.lr,
        "noise": cfg.noise.kind,
    }


def train(cfg, run_dir) -> dict:
    """Train (or resume, when `run_dir` holds a checkpoint) and return the run's summary."""
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    # Collection runs with one torch thread (MuJoCo's rollout threads own the cores) and the PPO
    # update with `torch_threads`: measured fastest on 2 cores (bench/update_time.py, docs).
    torch.set_num_threads(1)
    ckpt_path = run_dir / CHECKPOINT
    ckpt = torch.load(ckpt_path, weights_only=True) if ckpt_path.is_file() else None
    if ckpt is None:
        (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    torch.manual_seed(cfg.seed)

    env = make_env(cfg, seed=cfg.seed)
    obs = find_transform(env, PolicyObservation)
    actor, critic = make_models(cfg, obs.size, action_spec=env.action_spec)
    loss_module, advantage = make_loss(cfg, actor, critic)
    optimizer = torch.optim.Adam(loss_module.parameters(), lr=cfg.optim.lr)
    jd = find_transform(env, JumpingDistribution)
    css = find_transform(env, ControlledStartingState)
    evaluator = ProtocolEvaluator(cfg)

    fpb = int(cfg.collector.frames_per_batch)
    total = -(-int(cfg.collector.total_frames) // fpb) * fpb  # whole batches
    frames, batches, wall, history, best, best_error = 0, 0, 0.0, [], -1.0, math.inf
    timing = {"collect_seconds": 0.0, "update_seconds": 0.0, "batches": 0}  # this process only
    if ckpt is not None and int(ckpt["frames"]) >= total and (run_dir / "summary.json").is_file():
        print(f"{run_dir} already finished ({int(ckpt['frames'])} frames): nothing to resume")
        env.close()
        evaluator.env.close()
        return json.loads((run_dir / "summary.json").read_text())
    if ckpt is not None:
        actor.load_state_dict(ckpt["actor"])
        critic.load_state_dict(ckpt["critic"])
        optimizer.load_state_dict(ckpt["optimizer"])
        loss_module.load_state_dict(ckpt["loss"], strict=False)
        frames, batches, wall = int(ckpt["frames"]), int(ckpt["batches"]), float(ckpt["wall"])
        history, best = list(ckpt["history"]), float(ckpt["best"])
        best_error = float(ckpt.get("best_error", math.inf))
    collector = make_collector(env, actor, fpb, max(total - frames, fpb))
    if ckpt is not None:
        _restore_env_state(env, ckpt["env"])
        restore_carrier(collector, ckpt["carrier"])
        torch.set_rng_state(ckpt["torch_rng"])

    logger = TensorboardLogger(exp_name="tb", log_dir=str(run_dir)) if cfg.logger.tensorboard else None
    if logger is not None and ckpt is None:
        logger.experiment.add_text("config", "```\n" + OmegaConf.to_yaml(cfg, resolve=True) + "\n```", 0)

    def log(metrics: dict, step: int) -> None:
        if logger is not None:
            for k, v in metrics.items():
                if isinstance(v, (int, float)) and math.isfinite(v):
                    logger.log_scalar(k, v, step=step)

    def first_reach(level: float):
        for h in history:
            if h["eval/success_rate"] >= level:
                return {"frames": h["frames"], "wall_seconds": h["wall_seconds"]}
        return None

    def policy_info() -> dict:
        return {"frames": frames, "wall_seconds": round(wall, 1), "seed": int(cfg.seed)}

    def write_policy(path: Path) -> None:
        save_policy(
            path,
            actor,
            model=OmegaConf.to_container(cfg.model, resolve=True),
            env=OmegaConf.to_container(cfg.env, resolve=True),
            observation={"size": obs.size, "include_acceleration": obs.include_acceleration},
            info=policy_info(),
        )

    def checkpoint() -> None:
        atomic_save(
            {
                "frames": frames,
                "batches": batches,
                "wall": wall,
                "history": history,
                "best": best,
                "best_error": best_error,
                "actor": actor.state_dict(),
                "critic": critic.state_dict(),
                "optimizer": optimizer.state_dict(),
                "loss": loss_module.state_dict(),
                "env": _env_state(env),
                "carrier": carrier_state(collector),
                "torch_rng": torch.get_rng_state(),
            },
            ckpt_path,
        )

    def evaluate() -> dict:
        nonlocal best, best_error
        t0 = time.perf_counter()
        metrics = evaluator(actor)
        metrics["time/eval_seconds"] = time.perf_counter() - t0
        history.append({"frames": frames, "wall_seconds": round(wall, 1), **metrics})
        log(metrics, frames)
        # Success saturates at 1.0 early, so ties are common: among them the more precise hover wins.
        better = (metrics["eval/success_rate"], -metrics["eval/position_error"]) >= (best, -best_error)
        if better:
            best, best_error = metrics["eval/success_rate"], metrics["eval/position_error"]
        if better or not cfg.checkpoint.keep_best:
            write_policy(run_dir / "policy.pt")
        return metrics

    progress = None
    if cfg.logger.progress:
        from tqdm import tqdm

        progress = tqdm(total=total, initial=frames, unit="frames", unit_scale=True, dynamic_ncols=True)
    next_eval = (frames // cfg.eval.interval_frames + 1) * cfg.eval.interval_frames
    next_ckpt = (frames // cfg.checkpoint.interval_frames + 1) * cfg.checkpoint.interval_frames
    last_success = history[-1]["eval/success_rate"] if history else float("nan")
    if ckpt is None:
        last_success = evaluate()["eval/success_rate"]  # the untrained policy, at frame 0

    t_batch = time.perf_counter()
    for data in collector:
        t_collected = time.perf_counter()
        n = data.numel()
        frames += n
        batches += 1
        torch.set_num_threads(cfg.torch_threads)  # the update: torch gets the cores
        if cfg.optim.anneal_lr:  # linear decay to 0 at the last frame (CleanRL's recipe)
            for group in optimizer.param_groups:
                group["lr"] = cfg.optim.lr * max(0.0, 1.0 - (frames - n) / total)
        metrics = ppo_update(data, loss_module, advantage, optimizer, cfg)
        metrics["train/lr"] = optimizer.param_groups[0]["lr"]
        collector.update_policy_weights_()
        t_updated = time.perf_counter()
        wall += t_updated - t_batch
        metrics.update(episode_stats(data))
        metrics["train/reward"] = data.get(("next", keys.REWARD)).mean().item()
        metrics["time/fps"] = n / (t_updated - t_batch)
        metrics["time/collect_seconds"] = t_collected - t_batch
        metrics["time/update_seconds"] = t_updated - t_collected
        timing["collect_seconds"] += t_collected - t_batch
        timing["update_seconds"] += t_updated - t_collected
        timing["batches"] += 1
        metrics["time/wall_seconds"] = wall
        metrics["train/policy_std"] = actor.module[0].module.log_std.exp().mean().item()
        metrics["train/physics_failures"] = float(env.base_env.physics_failures)
        if jd is not None:
            metrics["train/jd_probability"] = jd.probability
        else:
            metrics["train/jd_probability"] = 0.0
        if batches % cfg.logger.log_interval == 0:
            log(metrics, frames)
        if frames >= next_eval or frames >= total:
            last_success = evaluate()["eval/success_rate"]
            next_eval += cfg.eval.interval_frames
            if css is not None and logger is not None:
                logger.experiment.add_figure("css/square_values", css_figure(css), frames)
        if frames >= next_ckpt or frames >= total:
            checkpoint()
            next_ckpt += cfg.checkpoint.interval_frames
        if progress is not None:
            progress.update(n)
            progress.set_postfix(fps=f"{metrics['time/fps']:.0f}", success=f"{last_success:.2f}", refresh=False)
        torch.set_num_threads(1)  # collection: MuJoCo's threads get the cores
        t_batch = time.perf_counter()
        if frames >= total:
            break
    collector.shutdown()
    if progress is not None:
        progress.close()

    write_policy(run_dir / "policy_last.pt")
    if not (run_dir / "policy.pt").exists():
        write_policy(run_dir / "policy.pt")
    summary = {
        "frames": frames,
        "wall_seconds": round(wall, 1),
        "final_success_rate": history[-1]["eval/success_rate"] if history else None,
        "best_success_rate": best,
        "first_reached_0.905": first_reach(PAPER_SUCCESS),
        "first_reached_0.99": first_reach(0.99),
        "collection_frames_per_second": round(
            timing["batches"] * cfg.collector.frames_per_batch / max(timing["collect_seconds"], 1e-9)
        ),
        "update_seconds_per_batch": round(timing["update_seconds"] / max(timing["batches"], 1), 3),
        "history": history,
    }
    (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
    if logger is not None:
        final = {"hparam/success_rate": summary["final_success_rate"] or 0.0, "hparam/best_success_rate": best}
        logger.experiment.add_hparams(_hparams(cfg), final, run_name="hparams")
        logger.experiment.flush()
    env.close()
    evaluator.env.close()
    return summary
