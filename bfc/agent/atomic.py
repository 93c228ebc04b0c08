"""Output files written whole or not at all: what the policy file, the checkpoints and both exports
share. A reader never sees half a file, and a failed write leaves nothing behind."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path


def check_output_path(path: Path, example: str) -> None:
    """A file path that can be written: not a directory, and no file where a folder of it should be.
    `example` names the kind of file asked for (`policy.onnx`)."""
    if path.is_dir():
        raise IsADirectoryError(f"the output path {path} is a directory: give a file name such as {example}")
    blocking = next((p for p in path.parents if p.exists() and not p.is_dir()), None)
    if blocking is not None:
        raise NotADirectoryError(f"cannot write {path}: {blocking} is a file, not a directory")


def atomic_write(path, write: Callable[[Path], None], what: str | None = None) -> Path:
    """`write(tmp)` to a temporary name beside `path`, then rename it to `path` (its folders made).
    With `what` ("the C header"), an OSError says what could not be written where."""
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        write(tmp)
        tmp.replace(path)
    except OSError as err:
        if what is None:
            raise
        raise OSError(f"cannot write {what} to {path}: {err.strerror or err}") from err
    finally:
        if tmp.parent.is_dir():
            tmp.unlink(missing_ok=True)
    return path
