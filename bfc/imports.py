"""A launch's imports for less.

Some libraries import an optional package whenever it is installed, for a feature bfc never uses
(TorchRL's Ray replay buffer, TensorBoard's S3 file system): each costs a training launch a tenth
of a second or more. `without(...)` hides such packages for the import alone. And Python's
garbage collector, scanning the imported objects again and again, costs a quarter of the launch:
train.py holds it while it imports (`hold_garbage_collection`, `release_garbage_collection`).
"""

from __future__ import annotations

import contextlib
import gc
import sys


@contextlib.contextmanager
def without(*names: str):
    """While the block runs, `import <name>` fails and `importlib.util.find_spec(<name>)` says "not
    installed" for each of `names` not loaded yet; afterwards they import as usual. A name that is
    loaded already (a sweep's launcher imported Ray first) is left alone."""
    hidden = [name for name in names if name not in sys.modules]
    for name in hidden:
        sys.modules[name] = None
    try:
        yield
    finally:
        for name in hidden:
            if name in sys.modules and sys.modules[name] is None:
                del sys.modules[name]


def hold_garbage_collection() -> None:
    """Python's cyclic garbage collector off while a launch imports: torch, TorchRL, Hydra and
    bfc make hundreds of thousands of objects that live as long as the process, and each
    collection of the oldest generation scans them all again (a quarter of a training's launch
    here: docs/training.md). `release_garbage_collection` turns it back on."""
    gc.disable()


def release_garbage_collection() -> None:
    """The collector back on, with everything made so far frozen out of its sight (`gc.freeze`:
    modules, classes and tensors that live as long as the run, which later collections then need
    not scan). Call it before any process forks (a child keeps its parent's setting). Does nothing
    where the collector is on (it was never held)."""
    if not gc.isenabled():
        gc.freeze()
        gc.enable()
