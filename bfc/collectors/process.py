"""A child process of the learner (a collector worker, the background evaluator), seen from the
learner: one pipe each way, tensors copied through it, a death that is an error, never a wait.

A child is forked, binds itself to the learner (bfc.lifetime.bind_to_parent: it dies with it and
leaves SIGINT and SIGTERM to it) and answers commands; an exception in it reaches the learner as
the one line a ValueError is, or as a RuntimeError with the child's traceback.
"""

from __future__ import annotations

import contextlib
import os
import pickle
import traceback

import torch

from bfc.lifetime import WorkerDied, death_cause


class ChildProcess:
    """A pipe each way (a socket pair; its far end closed here, so a dead child reads as
    end-of-file, never as a wait), the process, and the messages received before they were asked
    for. Messages are plain pickles of numpy arrays: copies through the pipe, no shared-memory
    segment per message and no file descriptor passed between the processes."""

    def __init__(self, ctx, name: str, what: str):
        """name: the process's name (ps, top); what: how errors name it ("collector worker 0")."""
        self.ctx, self.name, self.what = ctx, name, what
        self.conn, self.process = None, None
        self.pending: list = []  # messages received before they were asked for

    def start(self, target, *args) -> None:
        """Fork `target(conn, learner_end, parent_pid, name, *args)`."""
        self.conn, far = self.ctx.Pipe(duplex=True)
        full = (far, self.conn, os.getpid(), self.name, *args)
        self.process = self.ctx.Process(target=target, args=full, daemon=True, name=self.name)
        self.process.start()
        far.close()  # the child holds the only copy: its death closes the pipe

    def send(self, *message) -> None:
        try:
            self.conn.send_bytes(dumps(message))
        except OSError:  # a broken pipe: the child is gone
            raise self._died() from None

    def receive(self, kind: str):
        """The next message of `kind` (one received earlier first); others are kept for later."""
        for i, message in enumerate(self.pending):
            if message[0] == kind:
                return self.pending.pop(i)
        while True:
            try:
                if not self.conn.poll(1.0):
                    if not self.process.is_alive():
                        raise self._died()
                    continue
                message = loads(self.conn.recv_bytes())
            except (EOFError, OSError):
                raise self._died() from None
            if message[0] == "error":
                _, name, text, trace = message
                if name == "ValueError":  # bad input reaches the user as the one line it is
                    raise ValueError(text)
                raise RuntimeError(f"{self.what} failed: {trace}")
            if message[0] == kind:
                return message
            self.pending.append(message)

    def _died(self) -> WorkerDied:
        self.process.join(timeout=5)
        return WorkerDied(f"{self.what} (pid {self.process.pid}) died: {death_cause(self.process.exitcode)}")

    def stop(self) -> None:
        if self.process is not None and self.process.is_alive():
            with contextlib.suppress(WorkerDied):
                self.send("stop")
            self.process.join(timeout=10)
            if self.process.is_alive():
                self.process.kill()  # it ignores SIGTERM (bfc.lifetime.bind_to_parent)
                self.process.join(timeout=5)
        if self.conn is not None:
            self.conn.close()
        self.conn, self.process = None, None


def report_error(conn, err: Exception) -> None:
    """In a child: send `err` to the learner, which raises it (ChildProcess.receive)."""
    with contextlib.suppress(OSError):
        conn.send_bytes(dumps(("error", type(err).__name__, str(err), traceback.format_exc(limit=5))))


def dumps(message) -> bytes:
    """Tensors as numpy arrays (their exact bytes), so plain pickle copies them: torch's own
    reduction would share each through a new shared-memory segment and a passed descriptor."""
    return pickle.dumps(_tree(message, torch.Tensor, lambda t: _Array(t.detach().numpy())), pickle.HIGHEST_PROTOCOL)


def loads(data: bytes):
    return _tree(pickle.loads(data), _Array, lambda a: torch.from_numpy(a.array))


def _tree(x, kind, leaf):
    """`x` (dicts, lists and tuples of anything) with every `kind` in it replaced by `leaf(it)`."""
    if isinstance(x, kind):
        return leaf(x)
    if isinstance(x, dict):
        return {k: _tree(v, kind, leaf) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return type(x)(_tree(v, kind, leaf) for v in x)
    return x


class _Array:
    """A tensor in transit (a numpy array that the message's own arrays can be told apart from)."""

    __slots__ = ("array",)

    def __init__(self, array):
        self.array = array

    def __reduce__(self):
        return _Array, (self.array,)
