"""A process tree and what it may leave behind, read from /proc (Linux): the lifetime tests and
bench/soak.py look at a run from outside with these."""

import os
import tempfile
from pathlib import Path


def leftovers() -> set[str]:
    """What a run could leave on the machine: shared-memory segments and multiprocessing's sockets."""
    shm = {f"/dev/shm/{n}" for n in os.listdir("/dev/shm")} if os.path.isdir("/dev/shm") else set()
    return shm | {str(p) for p in Path(tempfile.gettempdir()).glob("pymp-*")}


def _stat(pid) -> list[str]:
    """/proc/<pid>/stat's fields after the command name (state, ppid, ...)."""
    return Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()


def children(pid: int) -> list[int]:
    found = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            if int(_stat(stat.parent.name)[1]) == pid:
                found.append(int(stat.parent.name))
        except (OSError, ValueError, IndexError):
            continue
    return sorted(found)


def alive(pid: int) -> bool:
    """A process that exists and is not a zombie (a reaped or unreaped corpse holds no memory)."""
    try:
        return _stat(pid)[0] != "Z"
    except (OSError, IndexError):
        return False


def descendants(pid: int) -> list[int]:
    """Every process below `pid`: its children, theirs, and so on."""
    found, todo = [], [pid]
    while todo:
        below = children(todo.pop())
        found += below
        todo += below
    return found


def name(pid: int) -> str:
    """The name `ps` and `top` show (empty for a process that is gone)."""
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""
