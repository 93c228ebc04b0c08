"""The one module that reaches into Hydra's internals (written against hydra-core 1.3).

Before a run Hydra composes the whole config once only to read `hydra.mode` (`Hydra.get_mode`)
and then composes it again for the run: the first composition is 0.1-0.2 s of every launch, and
for bfc's configs it always answers None (no file in conf/ sets `hydra.mode`: tested), which
Hydra then reads as "RUN, or MULTIRUN with -m". `skip_mode_probe` makes it answer None without
composing unless an override sets `hydra.mode` itself; tests/test_hydra_compat.py fails if
Hydra's answer for the repository's configs stops being None, or the method moves.
"""

from __future__ import annotations

import functools

HYDRA_VERSIONS = "1.3"  # the versions this reach was written and tested against


def sets_mode(overrides) -> bool:
    """Whether a command-line override sets `hydra.mode` (`hydra.mode=...`, `+`, `++` or `~`)."""
    return any(o.split("=", 1)[0].lstrip("+~") == "hydra.mode" for o in overrides)


def skip_mode_probe() -> None:
    """Have Hydra skip the composition that only reads `hydra.mode`, for the repository's configs
    (the caller's to check: bfc.cli.precheck). Does nothing on another Hydra version."""
    import hydra
    from hydra._internal.hydra import Hydra

    if not hydra.__version__.startswith(HYDRA_VERSIONS) or getattr(Hydra.get_mode, "probe_skipped", False):
        return
    probe = Hydra.get_mode

    @functools.wraps(probe)
    def get_mode(self, config_name, overrides):
        return probe(self, config_name, overrides) if sets_mode(overrides) else None

    get_mode.probe_skipped = True
    Hydra.get_mode = get_mode
