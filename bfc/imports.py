"""Importing a library with optional packages it would load for nothing kept out.

Some libraries import an optional package whenever it is installed, for a feature bfc never uses
(TorchRL's Ray replay buffer, TensorBoard's S3 file system): each costs a training launch a tenth
of a second or more. `without(...)` hides such packages for the import alone.
"""

from __future__ import annotations

import contextlib
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
