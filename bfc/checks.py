"""The one argument check every room uses: a ValueError that names the config key and what is allowed.

A leaf module (like bfc.keys): the env, the transforms and the config all import it, and it
imports nothing from bfc.
"""

from __future__ import annotations

import math


def check(cond: bool, key: str, allowed: str, value) -> None:
    """Raise `ValueError("<key> must be <allowed>, got <value>")` unless `cond`."""
    if not cond:
        raise ValueError(f"{key} must be {allowed}, got {value!r}")


def finite(v) -> bool:
    """A finite int or float (not a bool, not a string): what a numeric setting must be."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
