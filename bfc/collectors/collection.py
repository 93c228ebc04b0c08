"""What the runner collects from: the env, its curriculum and a collector, in the learner's
process (`LocalCollection`) or in a worker process that collects the next batch while the learner
updates on the last (`AsyncCollection`, `collector.workers=1`).

Either way the runner sees one interface: iterate for batches, `stats()` for the world the last
batch was collected in (JD's probability, TDTS events, physics failures, the curriculum, CSS's
square values), `update_policy_weights_()` after each update, `state_dict()` / `load_state_dict()`
for checkpoints, `close()`.
"""

from __future__ import annotations

import queue
import traceback

import torch
from omegaconf import OmegaConf
from tensordict import TensorDict

from bfc.collectors.collector import make_collector
from bfc.collectors.curriculum import Curriculum
from bfc.factory import find_transform, make_env
from bfc.transforms import ControlledStartingState, JumpingDistribution, TimeDependentTerminalState


def make_collection(cfg, net, total_frames: int):
    """The collection `collector.workers` asks for, flying the policy network `net`."""
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
        self.curriculum = Curriculum(cfg, self.env, self.jd)
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
    """A worker process collects batch i+1 while this process updates on batch i: collection and
    update overlap on two cores, and batch i+1 is flown with the weights from before update i
    (the policy one update behind; batches 0 and 1 both fly the initial weights). PPO's ratio is
    taken against the log-probabilities recorded at collection, so the lag is what it corrects.

    The worker is a `LocalCollection` with one MuJoCo thread (unless `env.num_threads` says
    otherwise), its own torch generator seeded by `seed` and a copy of the network, refreshed from
    shared memory at each update. Every exchange is in a fixed order, so a run is reproducible by
    seed on one machine; it is not the same run as `collector.workers=0` (the lag, and the
    worker's own generator). A checkpoint holds the worker's whole state and the batches it had
    sent that the learner had not yet used, so a resumed run is bit-identical too.
    """

    def __init__(self, cfg, net, total_frames: int):
        self.cfg, self.net, self.total = cfg, net, int(total_frames)
        self.fpb = int(cfg.collector.frames_per_batch)
        ctx = torch.multiprocessing.get_context("fork")
        # two slots of weights: the worker reads version v from slot v % 2 while the learner writes v + 1
        self.slots = [{k: v.detach().clone().share_memory_() for k, v in net.state_dict().items()} for _ in range(2)]
        self.commands, self.replies = ctx.Queue(), ctx.Queue()
        self.ctx, self.process = ctx, None
        self.version, self.frames = 0, 0  # updates published, frames handed to the learner
        self.pending: list = []  # batches received but not yet handed out
        self.resume: dict | None = None
        self._stats, self._css = {}, None

    # ------------------------------------------------------------------ the worker process
    def _start(self) -> None:
        if self.process is not None:
            return
        cfg = OmegaConf.to_container(self.cfg, resolve=True)
        args = (cfg, self.slots, self.commands, self.replies, self.total, self.resume)
        self.process = self.ctx.Process(target=_work, args=args, daemon=True, name="bfc-collector")
        self.process.start()

    def _receive(self, kind: str):
        while True:
            try:
                message = self.replies.get(timeout=1.0)
            except queue.Empty:
                if not self.process.is_alive():
                    raise RuntimeError(
                        f"the collector process died (exit code {self.process.exitcode}) without a word"
                    ) from None
                continue
            if message[0] == "error":
                raise RuntimeError(f"the collector process failed: {message[1]}")
            if message[0] == kind:
                return message
            if message[0] == "batch":  # a batch that came before the reply asked for: keep it
                self.pending.append(message)
            else:
                raise RuntimeError(f"unexpected message from the collector process: {message[0]!r}")

    def __iter__(self):
        self._start()
        while self.frames < self.total:
            _, index, payload, stats, css = self.pending.pop(0) if self.pending else self._receive("batch")
            n = int(self.cfg.env.num_envs)
            batch = TensorDict.from_dict(payload, batch_size=[n, self.fpb // n])
            self._stats, self._css = stats, css
            self.frames += batch.numel()
            yield batch

    def stats(self) -> dict:
        return dict(self._stats)

    def css_values(self):
        return self._css

    def update_policy_weights_(self) -> None:
        """Publish the learner's new weights (the next version) for the worker's batch after next."""
        self.version += 1
        slot = self.slots[self.version % 2]
        for k, v in self.net.state_dict().items():
            slot[k].copy_(v)
        self.commands.put(("weights", self.version))

    def state_dict(self) -> dict:
        """The worker's state (after the batches it has sent) and the batches not yet handed out."""
        self._start()
        self.commands.put(("snapshot",))
        _, worker = self._receive("state")
        pending = [list(m) for m in self.pending]
        return {"worker": worker, "pending": pending, "version": self.version, "frames": self.frames}

    def load_state_dict(self, state: dict) -> None:
        if self.process is not None:
            raise RuntimeError("load the collection's state before iterating it")
        self.resume = state["worker"]  # its weights by version come with it
        self.pending = [tuple(m) for m in state["pending"]]
        self.version, self.frames = int(state["version"]), int(state["frames"])

    def close(self) -> None:
        if self.process is not None and self.process.is_alive():
            self.commands.put(("stop",))
            self.process.join(timeout=10)
            if self.process.is_alive():
                self.process.terminate()
        self.process = None


class _Stop(Exception):
    pass


def _work(cfg: dict, slots, commands, replies, total_frames: int, resume: dict | None) -> None:
    """The collector process: batch i flies the weights after i - 1 updates (the initial ones for
    batches 0 and 1) while the learner runs update i - 1; every command is handled in order
    whenever the worker waits for weights it does not have yet."""
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

        def handle(command) -> None:
            if command[0] == "weights":
                received[command[1]] = {k: v.clone() for k, v in slots[command[1] % 2].items()}
            elif command[0] == "snapshot":
                state = {"collection": local.state_dict(), "net": net.state_dict(), "received": received}
                replies.put(("state", {**state, "torch_rng": torch.get_rng_state(), "index": index}))
            elif command[0] == "stop":
                raise _Stop

        fpb = int(cfg.collector.frames_per_batch)
        batches = iter(local)
        while index * fpb < total_frames:
            need = max(0, index - 1)
            while need > 0 and need not in received:
                handle(commands.get())
            if need > 0:
                net.load_state_dict(received[need])
                received = {v: w for v, w in received.items() if v >= need}
            batch = next(batches)
            replies.put(("batch", index, batch.to_dict(), local.stats(), local.css_values()))
            index += 1
        while True:  # all collected: answer snapshots (and keep the weights) until stopped
            handle(commands.get())
    except _Stop:
        return
    except Exception:  # noqa: BLE001 - reported to the learner, which raises it
        replies.put(("error", traceback.format_exc(limit=5)))
