"""The training runner, in the shape of rsl_rl's OnPolicyRunner: learn / evaluate / save / load / log.

Everything a run writes goes under its run directory:
    tb/                      TensorBoard events (a resumed run appends here)
    config.yaml              the resolved config
    checkpoints/last.pt      the latest checkpoint (atomic: written to a temporary name, then renamed)
    checkpoints/previous.pt  the one before it: a resume falls back to it if last.pt is unreadable
    policy.pt                the deployable policy: the best in-training evaluation on the validation
                             starts (highest success rate, then lowest eval/hover_error);
                             checkpoint.keep_best=false: the latest evaluated policy
    policy_last.pt           the policy at the end of training
    summary.json             frames, wall-clock, evaluation history, when 0.905 and 0.99 were first reached

A checkpoint is built from public state only: the models', the optimizer's and the loss's
`state_dict()`, the collector's `state_dict()` (env, transforms and the in-flight tensordict: see
ResumableCollector) and torch's RNG state.
"""

from __future__ import annotations

import copy
import json
import math
import os
import sys
import time
from pathlib import Path

import torch
from omegaconf import OmegaConf

from bfc import keys
from bfc.agent import PolicySpec, atomic_save, make_critic, save_policy, torchrl_actor
from bfc.agent.normalization import RewardScale
from bfc.collectors import episode_stats, make_collection
from bfc.evaluation.evaluator import ProtocolEvaluator
from bfc.imports import without
from bfc.lifetime import Preempted, SigtermGuard, WorkerDied
from bfc.training.background_eval import BackgroundEvaluator
from bfc.training.learners import learner_gamma, make_learner
from bfc.training.lr_schedule import adapt_to_kl, set_learning_rate

PAPER_SUCCESS = 0.905
CHECKPOINT = Path("checkpoints") / "last.pt"
PREVIOUS = Path("checkpoints") / "previous.pt"


def css_image(grid: torch.Tensor, pixels: int = 16) -> torch.Tensor:
    """CSS's square values (grid, grid), rows = y from -xy_range up, as a grey (1, H, W) image for
    TensorBoard: the lowest value black, the highest white, never-visited squares mid-grey, y up.
    Made without a plotting library, so training never imports one."""
    v = grid.clone()
    seen = ~torch.isnan(v)
    if bool(seen.any()):
        lo, hi = v[seen].min(), v[seen].max()
        v = torch.where(seen, (v - lo) / (hi - lo).clamp_min(1e-12), 0.5)
    else:
        v = torch.full_like(v, 0.5)
    v = v.flip(0).repeat_interleave(pixels, 0).repeat_interleave(pixels, 1)
    return v.unsqueeze(0)


def hparams(cfg) -> dict:
    return {
        "variant": cfg.variant,
        "algo": cfg.algo.name,
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


def read_checkpoint(run_dir: Path) -> dict | None:
    """The newest readable checkpoint of a run (None for a new run). An unreadable last.pt is
    reported and the previous checkpoint used; with no readable one left, a ValueError."""
    last, previous = run_dir / CHECKPOINT, run_dir / PREVIOUS
    if not last.exists() and not previous.exists():
        return None
    problems = []
    for path in (last, previous):
        if not path.exists():
            continue
        try:
            ckpt = torch.load(path, weights_only=True)
            if not isinstance(ckpt, dict) or "collector" not in ckpt:
                raise ValueError("not a bfc training checkpoint")
        except Exception as err:  # noqa: BLE001 - a truncated or foreign file: fall back one step
            problems.append(f"{path} is unreadable ({str(err).splitlines()[0][:120]})")
            continue
        if problems:
            print(f"warning: {problems[0]}; resuming from {path} (one checkpoint earlier)", file=sys.stderr)
        return ckpt
    raise ValueError(f"cannot resume {run_dir}: " + "; ".join(problems))


def next_evaluation(frames: int, e) -> int:
    """The frame count of the evaluation after `frames`: every `e.interval_frames`, and every
    `e.early_interval_frames` while below `e.early_frames` (a run that flies early is seen early)."""
    regular = (frames // e.interval_frames + 1) * e.interval_frames
    if frames >= e.early_frames:
        return regular
    return min(regular, (frames // e.early_interval_frames + 1) * e.early_interval_frames)


class Runner:
    """Builds everything a run needs from its config and trains it; `train(cfg, run_dir)` is
    `Runner(cfg, run_dir).learn()`. A run directory that holds a checkpoint is resumed."""

    def __init__(self, cfg, run_dir):
        self.cfg, self.run_dir = cfg, Path(run_dir)
        self.run_dir.mkdir(parents=True, exist_ok=True)
        torch.manual_seed(cfg.seed)
        self.spec = PolicySpec.from_config(cfg)
        self.net = self.spec.make_net()  # the policy: what policy.pt stores
        self.actor = torchrl_actor(self.net)  # TorchRL's view of it
        m = cfg.model
        self.critic = make_critic(self.spec.observation_size, m.critic_hidden, m.activation, self.net.obs_norm)
        self.learner = make_learner(cfg, self.actor, self.critic)
        # optim.normalize_reward: Baselines' VecNormalize on rewards, at the learner's discount
        self.reward_scale = RewardScale(cfg.env.num_envs, learner_gamma(cfg)) if cfg.optim.normalize_reward else None
        fpb = int(cfg.collector.frames_per_batch)
        self.total = -(-int(cfg.collector.total_frames) // fpb) * fpb  # whole batches
        # the env, its curriculum and the collector (here, or in a worker process)
        self.collection = make_collection(cfg, self.net, self.total)
        self.evaluator = None  # built at the first evaluation: the first batch starts sooner
        # eval.background: the validation flights in a process of their own while training goes on
        # (in place when a result must steer the run at once: stop_at_success, or when filmed)
        e, c = cfg.eval, cfg.collector
        background = e.background and c.stop_at_success is None and not cfg.logger.video
        self.background = BackgroundEvaluator(cfg) if background else None
        self.frames, self.batches, self.wall = 0, 0, 0.0
        self.history: list[dict] = []
        self.resumed_from: list[int] = []  # the frame counts this run was resumed at (killed, preempted)
        self.best, self.best_error = -1.0, math.inf
        self.timing = {"collect_seconds": 0.0, "update_seconds": 0.0, "batches": 0}  # this process only
        self.logger = None
        # the update's torch threads: torch_threads, every core (0), or the cores the workers leave (null)
        cores, workers = os.cpu_count() or 1, int(cfg.collector.workers)
        threads = cfg.torch_threads
        self.update_threads = max(1, cores - workers) if threads is None else int(threads or cores)
        self.stopped_early = False  # collector.stop_at_success was met
        self.paused = False  # checkpoint.pause_at_frames was reached
        self.collecting_since = time.time()  # unix seconds: start-up ends when collection starts (learn)
        self.saved_frames = None  # the frames of the newest checkpoint on disk
        self.sigterm = SigtermGuard()  # train() activates it: SIGTERM then checkpoints and raises Preempted

    # ------------------------------------------------------------------ save / load
    def state_dict(self) -> dict:
        return {
            "frames": self.frames,
            "batches": self.batches,
            "wall": self.wall,
            "history": self.history,
            "resumed_from": self.resumed_from,
            "best": self.best,
            "best_error": self.best_error,
            "actor": self.actor.state_dict(),
            "critic": self.critic.state_dict(),
            **self.learner.state_dict(),
            "collector": self.collection.state_dict(),
            "torch_rng": torch.get_rng_state(),
            **({"reward_scale": self.reward_scale.state_dict()} if self.reward_scale is not None else {}),
        }

    def save(self, path=None) -> None:
        """Write a checkpoint atomically (every evaluation so far in it); the one it replaces is kept as previous.pt."""
        self.take_evaluations()
        path = Path(path) if path is not None else self.run_dir / CHECKPOINT
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.exists():
            path.replace(path.with_name(PREVIOUS.name))
        atomic_save(self.state_dict(), path)
        self.saved_frames = self.frames

    def load(self, ckpt: dict) -> None:
        try:
            self.actor.load_state_dict(ckpt["actor"])
            self.critic.load_state_dict(ckpt["critic"])
            self.learner.load_state_dict(ckpt)
            self.frames, self.batches, self.wall = int(ckpt["frames"]), int(ckpt["batches"]), float(ckpt["wall"])
            self.history, self.best = list(ckpt["history"]), float(ckpt["best"])
            self.resumed_from = [*ckpt["resumed_from"], self.frames]
            self.best_error = float(ckpt["best_error"])
            self.collection.load_state_dict(ckpt["collector"])
            if self.reward_scale is not None:
                self.reward_scale.load_state_dict(ckpt["reward_scale"])
        except (KeyError, RuntimeError, ValueError) as err:
            first = str(err).strip().splitlines()[0][:200] if str(err).strip() else type(err).__name__
            raise ValueError(
                f"cannot resume {self.run_dir}: its checkpoint does not fit this bfc version's run ({first})"
            ) from None
        torch.set_rng_state(ckpt["torch_rng"])

    def write_policy(self, path: Path, net=None, entry: dict | None = None) -> None:
        """`net` (the policy's own by default) as a policy file, with the frames and wall-clock of `entry` (now)."""
        entry = entry or {"frames": self.frames, "wall_seconds": round(self.wall, 1)}
        info = {"frames": entry["frames"], "wall_seconds": entry["wall_seconds"], "seed": int(self.cfg.seed)}
        save_policy(path, self.spec, net or self.net, info)

    # ------------------------------------------------------------------ log / evaluate
    def log(self, metrics: dict, step: int) -> None:
        if self.logger is not None:
            for k, v in metrics.items():
                if isinstance(v, (int, float)) and math.isfinite(v):
                    self.logger.add_scalar(k, v, global_step=step)

    def evaluate(self) -> None:
        """The protocol on the validation starts, here or in the background evaluator (whose
        earlier results are taken first, in order); keeps policy.pt as the best so far."""
        entry = {"frames": self.frames, "wall_seconds": round(self.wall, 1)}
        if self.background is not None:
            self.take_evaluations()
            self.background.submit(self.net, entry)
            return
        t0 = time.perf_counter()
        if self.evaluator is None:
            self.evaluator = ProtocolEvaluator(self.cfg)
        metrics = self.evaluator(self.net)
        metrics["time/eval_seconds"] = time.perf_counter() - t0
        self.record_evaluation(entry, metrics, time.time())
        if self.cfg.logger.video and self.logger is not None:
            summary = self.evaluator.video(f"frame {self.frames:,}:")
            self.logger.file_writer.add_summary(summary, self.frames)  # public: SummaryWriter's own writer

    def take_evaluations(self) -> None:
        """The background evaluator's results so far (waiting for any still flying), recorded in order."""
        if self.background is None:
            return
        for entry, weights, metrics, unix in self.background.results():
            self.record_evaluation(entry, metrics, unix, weights)

    def record_evaluation(self, entry: dict, metrics: dict, unix: float, weights: dict | None = None) -> None:
        """History, logs and policy.pt for one evaluation of `weights` (None: the net as it is)."""
        # unix_seconds: when the evaluation ended, so a benchmark can count from process start
        self.history.append({**entry, "unix_seconds": round(unix, 2), **metrics})
        self.log(metrics, entry["frames"])
        # Success saturates at 1.0 early, so ties are common: among them the more precise hover wins.
        error = metrics.get("eval/hover_error", math.inf)
        better = (metrics["eval/success_rate"], -error) >= (self.best, -self.best_error)
        if better:
            self.best, self.best_error = metrics["eval/success_rate"], error
        if better or not self.cfg.checkpoint.keep_best:
            net = self.net
            if weights is not None:  # a copy of the net (a new one would draw its init from torch's generator)
                net = copy.deepcopy(self.net)
                net.load_state_dict(weights)
            self.write_policy(self.run_dir / "policy.pt", net, entry)

    def should_stop(self) -> bool:
        """collector.stop_at_success: the last `stop_patience` evaluations (after frame 0) all reached it."""
        c = self.cfg.collector
        if c.stop_at_success is None:
            return False
        recent = [h["eval/success_rate"] for h in self.history if h["frames"] > 0][-c.stop_patience :]
        return len(recent) == c.stop_patience and min(recent) >= c.stop_at_success

    def pause_due(self) -> bool:
        pause = self.cfg.checkpoint.pause_at_frames
        return pause is not None and self.frames >= pause

    def first_reach(self, level: float):
        for h in self.history:
            if h["eval/success_rate"] >= level:
                return {"frames": h["frames"], "wall_seconds": h["wall_seconds"]}
        return None

    # ------------------------------------------------------------------ learn
    def learn(self) -> dict:
        """Train to collector.total_frames (from the checkpoint, if any) and return the summary."""
        cfg, run_dir = self.cfg, self.run_dir
        ckpt = read_checkpoint(run_dir)
        if ckpt is None:
            config_yaml = OmegaConf.to_yaml(cfg, resolve=True)  # config.yaml, and TensorBoard's text
            (run_dir / "config.yaml").write_text(config_yaml)
        elif (run_dir / "summary.json").is_file() and (
            int(ckpt["frames"]) >= self.total or json.loads((run_dir / "summary.json").read_text()).get("stopped_early")
        ):
            print(f"{run_dir} already finished ({int(ckpt['frames'])} frames): nothing to resume")
            return json.loads((run_dir / "summary.json").read_text())
        else:
            self.load(ckpt)
            self.saved_frames = self.frames
            if self.pause_due():  # already there (a kill after the pause point, or the same pause again)
                print(f"{run_dir} is paused at {self.frames} frames (checkpoint.pause_at_frames): nothing to train")
                self.paused = True
                return self._finish()  # the summary and policy files of the checkpoint's state
        if cfg.logger.tensorboard:
            # torch's SummaryWriter, which TorchRL's TensorboardLogger wraps (importing it alone
            # saves TorchRL's record package's 0.4 s of start-up); events go to <run dir>/tb, a
            # local folder, so TensorBoard's S3 and fsspec file systems stay unloaded (0.1 s)
            with without("boto3", "fsspec"):
                from torch.utils.tensorboard import SummaryWriter

            if cfg.logger.video:  # no renderer: one line now, not a failure at the first evaluation
                from bfc.evaluation.video import RendererUnavailable, check_renderer

                try:
                    check_renderer()
                except RendererUnavailable as err:
                    raise ValueError(f"logger.video=true: {err}") from None
            self.logger = SummaryWriter(log_dir=str(run_dir / "tb"))
            if ckpt is None:
                text = "```\n" + config_yaml + "\n```"
                self.logger.add_text("config", text, 0)

        progress = None
        if cfg.logger.progress:
            from tqdm import tqdm

            progress = tqdm(total=self.total, initial=self.frames, unit="frames", unit_scale=True, dynamic_ncols=True)
        e, c = cfg.eval, cfg.checkpoint
        next_eval = next_evaluation(self.frames, e)
        next_ckpt = (self.frames // c.interval_frames + 1) * c.interval_frames
        if self.background is not None:
            self.background.start()
        if ckpt is None and e.at_start:
            self.evaluate()  # the untrained policy, at frame 0

        self.collecting_since = time.time()  # unix seconds: start-up ends here (bench/startup.py)
        t_batch = time.perf_counter()
        for data in self.collection:
            t_collected = time.perf_counter()
            metrics = self._update(data)
            t_updated = time.perf_counter()
            self.wall += t_updated - t_batch
            n = data.numel()
            metrics.update(self._batch_metrics(data, t_batch, t_collected, t_updated))
            if self.batches % cfg.logger.log_interval == 0:
                self.log(metrics, self.frames)
            if self.frames >= next_eval or self.frames >= self.total:
                self.evaluate()
                next_eval = next_evaluation(self.frames, e)
                css = self.collection.css_values()
                if css is not None and self.logger is not None:
                    self.logger.add_image("css/square_values", css_image(css[0]), self.frames)
                self.stopped_early = self.frames < self.total and self.should_stop()
            self.paused = self.frames < self.total and not self.stopped_early and self.pause_due()
            ending = self.frames >= self.total or self.stopped_early or self.paused
            preempted = self.sigterm.requested and not ending  # SIGTERM: checkpoint now, then stop
            if self.frames >= next_ckpt or ending or preempted:
                self.save()
                next_ckpt = (self.frames // c.interval_frames + 1) * c.interval_frames
            if progress is not None:
                last_success = self.history[-1]["eval/success_rate"] if self.history else float("nan")
                progress.update(n)
                progress.set_postfix(fps=f"{metrics['time/fps']:.0f}", success=f"{last_success:.2f}", refresh=False)
            if preempted:
                if progress is not None:
                    progress.close()
                raise Preempted(self.frames)
            torch.set_num_threads(1)  # collection: MuJoCo's threads get the cores
            t_batch = time.perf_counter()
            if ending:
                break
        if progress is not None:
            progress.close()
        return self._finish()

    def _update(self, data) -> dict:
        cfg = self.cfg
        n = data.numel()
        self.frames += n
        self.batches += 1
        torch.set_num_threads(self.update_threads)  # the update: torch gets the cores
        if cfg.optim.anneal_lr or cfg.optim.desired_kl is not None:
            anneal = max(0.0, 1.0 - (self.frames - n) / self.total) if cfg.optim.anneal_lr else 1.0
            set_learning_rate(self.learner.optimizers, anneal)
        batch = data
        if self.reward_scale is not None:  # the learner sees scaled rewards; the logs, the env's
            batch = data.clone()
            done = data.get(("next", keys.DONE))
            batch.set(("next", keys.REWARD), self.reward_scale(data.get(("next", keys.REWARD)), done))
        metrics = self.learner.update(batch, frames=self.frames - n)
        metrics["train/lr"] = self.learner.optimizers[0].param_groups[0]["lr"]
        if cfg.optim.desired_kl is not None:
            adapt_to_kl(self.learner.optimizers, metrics["loss/approx_kl"], cfg.optim.desired_kl)
        if self.net.obs_norm is not None:  # after the update: it scored the batch with the stats it was collected with
            self.net.obs_norm.update(data.get(keys.OBSERVATION))
        self.collection.update_policy_weights_()
        return metrics

    def _batch_metrics(self, data, t_batch: float, t_collected: float, t_updated: float) -> dict:
        n = data.numel()
        metrics = episode_stats(data)
        metrics["train/reward"] = data.get(("next", keys.REWARD)).mean().item()
        metrics["time/fps"] = n / (t_updated - t_batch)
        metrics["time/collect_seconds"] = t_collected - t_batch
        metrics["time/update_seconds"] = t_updated - t_collected
        self.timing["collect_seconds"] += t_collected - t_batch
        self.timing["update_seconds"] += t_updated - t_collected
        self.timing["batches"] += 1
        metrics["time/wall_seconds"] = self.wall
        metrics["train/policy_std"] = self.net.std.mean().item()
        metrics.update(self.collection.stats())  # the world of the batch just collected
        return metrics

    def _finish(self) -> dict:
        run_dir, cfg = self.run_dir, self.cfg
        self.take_evaluations()
        self.write_policy(run_dir / "policy_last.pt")
        if not (run_dir / "policy.pt").exists():
            self.write_policy(run_dir / "policy.pt")
        summary = {
            "frames": self.frames,
            "wall_seconds": round(self.wall, 1),
            "final_success_rate": self.history[-1]["eval/success_rate"] if self.history else None,
            "best_success_rate": self.best,
            "first_reached_0.905": self.first_reach(PAPER_SUCCESS),
            "first_reached_0.99": self.first_reach(0.99),
            "stopped_early": self.stopped_early,
            "paused": self.paused,  # checkpoint.pause_at_frames: the same command resumes it
            "collecting_since_unix_seconds": round(self.collecting_since, 3),
            "collection_frames_per_second": round(
                self.timing["batches"] * cfg.collector.frames_per_batch / max(self.timing["collect_seconds"], 1e-9)
            ),
            "update_seconds_per_batch": round(self.timing["update_seconds"] / max(self.timing["batches"], 1), 3),
            "resumed_from": self.resumed_from,
            "history": self.history,
        }
        (run_dir / "summary.json").write_text(json.dumps(summary, indent=1))
        if self.logger is not None and not self.paused:
            final = {"hparam/success_rate": summary["final_success_rate"] or 0.0, "hparam/best_success_rate": self.best}
            self.logger.add_hparams(hparams(cfg), final, run_name="hparams")
            self.logger.flush()
        return summary

    def close(self) -> None:
        if self.logger is not None:
            self.logger.close()
        self.collection.close()
        if self.evaluator is not None:
            self.evaluator.close()
        if self.background is not None:
            self.background.close()


def train(cfg, run_dir) -> dict:
    """Train (or resume, when `run_dir` holds a checkpoint) and return the run's summary.

    Collection in this process runs with one torch thread (MuJoCo's rollout threads own the
    cores), the update with `torch_threads` (null: the cores the collector workers leave); the
    caller's thread count is restored on return.
    """
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    runner = None
    try:
        runner = Runner(cfg, run_dir)
        with runner.sigterm:
            return runner.learn()
    except WorkerDied as err:
        if runner is None or runner.saved_frames is None:
            raise WorkerDied(f"{err}; no checkpoint was written yet: start the run again") from None
        hint = f"the run resumes from its last checkpoint ({runner.saved_frames} frames) with resume={run_dir}"
        raise WorkerDied(f"{err}; {hint}") from None
    finally:
        if runner is not None:
            runner.close()
        torch.set_num_threads(threads)
