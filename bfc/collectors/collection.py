"""What the runner collects from: the env, its curriculum and a collector, in the learner's
process (`LocalCollection`) or in worker processes that collect the next batch while the learner
updates on the last (`AsyncCollection`, `collector.workers=k`).

Either way the runner sees one interface: iterate for batches, `stats()` for the world the last
batch was collected in (JD's probability, TDTS events, physics failures, the curriculum, CSS's
square values), `update_policy_weights_()` after each update, `state_dict()` / `load_state_dict()`
for checkpoints, `close()`.
"""

from __future__ import annotations

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict

from bfc.collectors.collector import make_collector
from bfc.collectors.curriculum import Curriculum
from bfc.collectors.process import ChildProcess, dumps, loads, report_error
from bfc.factory import find_transform, make_env
from bfc.lifetime import bind_to_parent
from bfc.transforms import (
    ActionDelay,
    ControlledStartingState,
    JumpingDistribution,
    ObservationDelay,
    TimeDependentTerminalState,
)


def make_collection(cfg, net, total_frames: int):
    """The collection `collector.workers` asks for (0: here; k: k worker processes), flying the
    policy network `net`."""
    if int(cfg.collector.workers) == 0:
        return LocalCollection(cfg, net, total_frames)
    return AsyncCollection(cfg, net, total_frames)


class LocalCollection:
    """`make_env(cfg, seed=cfg.seed)`, its curriculum (applied before every batch, from the frames
    collected so far) and the collector `collector.kind` names, in this process."""

    def __init__(self, cfg, net, total_frames: int, num_threads: int | None = None):
        if num_threads is not None:
            cfg = OmegaConf.merge(cfg, {"env": {"num_threads": num_threads}})
        self.env = make_env(cfg, seed=cfg.seed)
        self.jd = find_transform(self.env, JumpingDistribution)
        self.css = find_transform(self.env, ControlledStartingState)
        self.tdts = find_transform(self.env, TimeDependentTerminalState)
        delays = [t for t in (find_transform(self.env, c) for c in (ObservationDelay, ActionDelay)) if t is not None]
        self.curriculum = Curriculum(cfg, self.env, self.jd, delays)
        self.frames = 0
        self.curriculum.apply(0)  # before the collector's first reset
        fpb = int(cfg.collector.frames_per_batch)
        self.collector = make_collector(self.env, net, fpb, total_frames, kind=cfg.collector.kind)

    def __iter__(self):
        for batch in self.collector:
            self._stats = self._world(self.frames)
            self.frames += batch.numel()
            yield batch
            self.curriculum.apply(self.frames)  # the next batch's world, after the learner's update

    def _world(self, frames: int) -> dict:
        stats = {
            "train/physics_failures": float(self.env.base_env.physics_failures),
            "train/jd_probability": self.jd.probability if self.jd is not None else 0.0,
            "train/curriculum": self.curriculum.scale(frames),
        }
        if self.tdts is not None:
            stats["train/tdts_fired"] = float(self.tdts.fired)
        return stats

    def stats(self) -> dict:
        """The world of the batch just collected (train/* tags)."""
        return dict(self._stats)

    def css_values(self):
        """CSS's square values (grid, grid) and its start area's half-width, or None without CSS."""
        return None if self.css is None else (self.css.value_grid.clone(), self.css.xy_range)

    def update_policy_weights_(self) -> None:
        self.collector.update_policy_weights_()

    def state_dict(self) -> dict:
        return {"collector": self.collector.state_dict(), "frames": self.frames}

    def load_state_dict(self, state: dict) -> None:
        self.collector.load_state_dict(state["collector"])
        self.frames = int(state["frames"])
        self.curriculum.apply(self.frames)

    def close(self) -> None:
        self.collector.shutdown()
        self.env.close()


class AsyncCollection:
    """Worker processes collect batch i+1 while this process updates on batch i: collection and
    update overlap, and batch i+1 is flown with the weights from before update i (the policy one
    update behind; batches 0 and 1 both fly the initial weights). PPO's ratio is taken against
    the log-probabilities recorded at collection, so the lag is what it corrects.

    With `collector.workers=k`, each worker is a `LocalCollection` of num_envs / k envs (its own
    seed: `seed` for the first, `seed + 1000 w` for worker w; every frame-counted schedule, JD's
    decay and the curriculum, divided by k so that it follows the run's total frames), one MuJoCo
    thread unless `env.num_threads` says otherwise, its own torch generator and a copy of the
    network refreshed from shared memory at each update; a batch is the workers' batches side by
    side (envs of worker 0 first). Every exchange is in a fixed order, so a run is reproducible by
    seed on one machine for a given k; it is not the same run as `collector.workers=0` (the lag,
    the workers' own generators) nor as another k. A checkpoint holds every worker's state and
    the batches they had sent that the learner had not used yet, so a resumed run is
    bit-identical too. A worker dies with this process, and one that dies raises `WorkerDied`
    here instead of leaving the learner waiting (bfc.lifetime).
    """

    def __init__(self, cfg, net, total_frames: int):
        self.cfg, self.net, self.total = cfg, net, int(total_frames)
        self.k = int(cfg.collector.workers)
        n, self.fpb = int(cfg.env.num_envs), int(cfg.collector.frames_per_batch)
        if n % self.k or self.fpb % self.k:
            raise ValueError(f"env.num_envs ({n}) must be a multiple of collector.workers ({self.k})")
        self.shape = (n, self.fpb // n)
        # bad env or transform values fail here, with their one-line message, not in a worker
        make_env(OmegaConf.create(worker_config(cfg, 0, self.k)), seed=int(cfg.seed)).close()
        self.ctx = torch.multiprocessing.get_context("fork")
        # two slots of weights: a worker copies version v out of slot v % 2 while the learner writes v + 1
        self.slots = [{k: v.detach().clone().share_memory_() for k, v in net.state_dict().items()} for _ in range(2)]
        self.workers = [_Worker(self.ctx, w) for w in range(self.k)]
        self.version, self.frames, self.started = 0, 0, False  # updates published, frames handed out
        self._stats, self._css = {}, None

    def _start(self) -> None:
        if self.started:
            return
        for worker in self.workers:
            worker.start(worker_config(self.cfg, worker.index, self.k), self.slots, self.total // self.k)
        self.started = True

    def __iter__(self):
        self._start()
        while self.frames < self.total:
            parts = [worker.receive("batch") for worker in self.workers]
            # the constructor, not from_dict: that asks every tensor whether it is a pandas DataFrame
            # (importing pandas, 0.3 s, on the first batch)
            batches = [TensorDict(p[2], batch_size=[self.shape[0] // self.k, self.shape[1]]) for p in parts]
            batch = batches[0] if self.k == 1 else torch.cat(batches, 0)
            self._stats = _merge([p[3] for p in parts])
            self._css = parts[0][4]
            self.frames += batch.numel()
            yield batch

    def stats(self) -> dict:
        return dict(self._stats)

    def css_values(self):
        return self._css

    def update_policy_weights_(self) -> None:
        """Publish the learner's new weights (the next version) for the workers' batch after next."""
        self.version += 1
        slot = self.slots[self.version % 2]
        for k, v in self.net.state_dict().items():
            slot[k].copy_(v)
        for worker in self.workers:
            worker.send("weights", self.version)

    def state_dict(self) -> dict:
        """Every worker's state (after the batches it has sent) and the batches not yet handed out."""
        self._start()
        for worker in self.workers:
            worker.send("snapshot")
        states = [worker.receive("state")[1] for worker in self.workers]
        pending = [[list(m) for m in worker.pending] for worker in self.workers]
        return {"workers": states, "pending": pending, "version": self.version, "frames": self.frames}

    def load_state_dict(self, state: dict) -> None:
        if self.started:
            raise RuntimeError("load the collection's state before iterating it")
        if len(state["workers"]) != self.k:
            raise ValueError(f"the checkpoint has {len(state['workers'])} collector workers, this run {self.k}")
        for worker, resume, pending in zip(self.workers, state["workers"], state["pending"], strict=True):
            worker.resume, worker.pending = resume, [tuple(m) for m in pending]  # weights by version come with it
        self.version, self.frames = int(state["version"]), int(state["frames"])

    def close(self) -> None:
        for worker in self.workers:
            worker.stop()
        self.started = False


def worker_config(cfg, w: int, k: int) -> dict:
    """Worker w's config of k: its share of the envs and frames, its seed, every frame-counted
    schedule divided by k (so that, counted on its own envs, it follows the whole run)."""
    from bfc.config import jd_decay_frames

    c = OmegaConf.to_container(cfg, resolve=True)
    if k > 1:
        c["env"]["num_envs"] //= k
        c["collector"]["frames_per_batch"] //= k
        c["collector"]["total_frames"] = int(cfg.collector.total_frames) // k
        c["jd"]["decay_frames"] = jd_decay_frames(cfg) // k
        c["curriculum"]["frames"] = int(cfg.curriculum.frames) // k
        c["seed"] = int(cfg.seed) + 1000 * w
    return c


def _merge(stats: list[dict]) -> dict:
    """The workers' world statistics as one: counts summed, schedules (the same in every worker) kept."""
    out = dict(stats[0])
    for key in ("train/physics_failures", "train/tdts_fired"):
        if key in out:
            out[key] = float(sum(s[key] for s in stats))
    return out


class _Worker(ChildProcess):
    """One collector process, seen from the learner (batches received before a reply that was
    asked for are kept, in order, in `pending`)."""

    def __init__(self, ctx, index: int):
        super().__init__(ctx, f"bfc-collector-{index}", f"collector worker {index}")
        self.index, self.resume = index, None

    def start(self, cfg: dict, slots, total_frames: int) -> None:
        super().start(_work, cfg, slots, total_frames, self.resume)


class _Stop(Exception):
    pass


def _work(conn, learner_end, parent: int, name: str, cfg: dict, slots, total_frames: int, resume: dict | None) -> None:
    """The collector process: batch i flies the weights after i - 1 updates (the initial ones for
    batches 0 and 1) while the learner runs update i - 1; every command is handled in order
    whenever the worker waits for weights it does not have yet. It dies with the learner."""
    learner_end.close()
    bind_to_parent(parent, name)
    try:
        torch.set_num_threads(1)
        cfg = OmegaConf.create(cfg)
        threads = cfg.env.num_threads if cfg.env.num_threads is not None else 1
        from bfc.agent import PolicySpec

        net = PolicySpec.from_config(cfg).make_net()
        net.load_state_dict(slots[0])
        torch.manual_seed(int(cfg.seed))
        local = LocalCollection(cfg, net, total_frames, num_threads=int(threads))
        received, index = {}, 0  # weights by version, copied out of their slot when announced
        if resume is not None:
            local.load_state_dict(resume["collection"])
            net.load_state_dict(resume["net"])
            torch.set_rng_state(resume["torch_rng"])
            received, index = dict(resume["received"]), int(resume["index"])

        def send(*message) -> None:
            conn.send_bytes(dumps(message))

        def handle(command) -> None:
            if command[0] == "weights":
                received[command[1]] = {k: v.clone() for k, v in slots[command[1] % 2].items()}
            elif command[0] == "snapshot":
                state = {"collection": local.state_dict(), "net": net.state_dict(), "received": received}
                send("state", {**state, "torch_rng": torch.get_rng_state(), "index": index})
            elif command[0] == "stop":
                raise _Stop

        def next_command():
            return loads(conn.recv_bytes())

        fpb = int(cfg.collector.frames_per_batch)
        batches = iter(local)
        while index * fpb < total_frames:
            need = max(0, index - 1)
            while need > 0 and need not in received:
                handle(next_command())
            if need > 0:
                net.load_state_dict(received[need])
                received = {v: w for v, w in received.items() if v >= need}
            batch = next(batches)
            send("batch", index, batch.to_dict(), local.stats(), local.css_values())
            index += 1
        while True:  # all collected: answer snapshots (and keep the weights) until stopped
            handle(next_command())
    except (_Stop, EOFError, BrokenPipeError, ConnectionResetError):  # asked to stop, or the learner is gone
        return
    except Exception as err:  # noqa: BLE001 - reported to the learner, which raises it
        report_error(conn, err)
