"""Training's validation flights in a process of their own, while training goes on (`eval.background`).

On 2 cores a default run keeps both busy, the learner's update on one and the collector worker's
next batch on the other, and an evaluation in the learner (100 flights of 10 s: 1.2-1.8 s, most
of it on one core) holds both: the worker waits for the weights of the update after it. Here the
learner hands a copy of the evaluated weights to an evaluator process and trains on. It takes the
metrics back, in order, at fixed points (the next evaluation, each checkpoint, the end), so the
history, policy.pt and every checkpoint are those of evaluating in place and a run reproduces by
seed as before; only the `unix_seconds` of an evaluation (when it ended) differ.
"""

from __future__ import annotations

import time

import torch
from omegaconf import OmegaConf

from bfc.collectors.process import ChildProcess, dumps, loads, report_error
from bfc.lifetime import bind_to_parent


class BackgroundEvaluator:
    """The evaluator process, seen from the learner: `submit` the net at an evaluation, `results`
    for every submitted one, in order."""

    def __init__(self, cfg):
        self.cfg = cfg
        self.child = None
        self.waiting: list = []  # (entry, weights) submitted and not yet taken back

    def start(self) -> None:
        """Fork the evaluator (before the learner's collection starts its threads)."""
        if self.child is None:
            ctx = torch.multiprocessing.get_context("fork")
            self.child = ChildProcess(ctx, "bfc-evaluator", "the background evaluator")
            self.child.start(_evaluate, OmegaConf.to_container(self.cfg, resolve=True))

    def submit(self, net, entry: dict) -> None:
        """Evaluate `net`'s weights now (a copy: training goes on changing them); `entry` comes back with them."""
        self.start()
        weights = {k: v.detach().clone() for k, v in net.state_dict().items()}
        self.child.send("evaluate", weights)
        self.waiting.append((entry, weights))

    def results(self) -> list:
        """(entry, weights, metrics, unix seconds when it ended) of every submitted evaluation, in
        order; waits for those still flying."""
        out = []
        while self.waiting:
            _, metrics, unix = self.child.receive("metrics")
            entry, weights = self.waiting.pop(0)
            out.append((entry, weights, metrics, unix))
        return out

    def close(self) -> None:
        if self.child is not None:
            self.child.stop()
            self.child = None


def _evaluate(conn, learner_end, parent: int, name: str, cfg: dict) -> None:
    """The evaluator process: one torch thread and one MuJoCo thread (the learner and the collector
    have the cores), a ProtocolEvaluator built at the first request; it dies with the learner."""
    learner_end.close()
    bind_to_parent(parent, name)
    try:
        from bfc.agent import PolicySpec
        from bfc.evaluation.evaluator import ProtocolEvaluator

        torch.set_num_threads(1)
        cfg = OmegaConf.create(cfg)
        cfg.env.num_threads = 1
        net, evaluator = PolicySpec.from_config(cfg).make_net(), None
        while True:
            command = loads(conn.recv_bytes())
            if command[0] == "stop":
                return
            evaluator = evaluator or ProtocolEvaluator(cfg)
            net.load_state_dict(command[1])
            t0 = time.perf_counter()
            metrics = evaluator(net)
            metrics["time/eval_seconds"] = time.perf_counter() - t0
            conn.send_bytes(dumps(("metrics", metrics, time.time())))
    except (EOFError, BrokenPipeError, ConnectionResetError):  # the learner is gone
        return
    except Exception as err:  # noqa: BLE001 - reported to the learner, which raises it
        report_error(conn, err)
