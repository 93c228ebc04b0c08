"""What train.py and evaluate.py share: the command line checked before Hydra runs, and bad input
reported as one `error: ...` line with exit status 2 (never a traceback)."""

from __future__ import annotations

import argparse
import sys

from bfc.lifetime import BAD_INPUT

# Hydra's own flags (hydra/_internal/utils.py, get_args_parser), so that the overrides among the
# arguments can be told apart; flags that take a value list it.
_HYDRA_FLAGS = {
    ("--cfg", "-c"): True,
    ("--package", "-p"): True,
    ("--config-path", "-cp"): True,
    ("--config-name", "-cn"): True,
    ("--config-dir", "-cd"): True,
    ("--experimental-rerun",): True,
    ("--info", "-i"): "?",
    ("--multirun", "-m"): False,
    ("--run", "-r"): False,
    ("--resolve",): False,
    ("--help", "-h"): False,
    ("--hydra-help",): False,
    ("--version",): False,
    ("--shell-completion", "-sc"): False,
}


def overrides_of(argv: list[str]) -> tuple[list[str], bool]:
    """(the Hydra overrides among `argv`, whether the config they apply to is the repository's)."""
    parser = argparse.ArgumentParser(add_help=False)
    for flags, value in _HYDRA_FLAGS.items():
        if value is True:
            parser.add_argument(*flags)
        elif value == "?":
            parser.add_argument(*flags, nargs="?", const="")
        else:
            parser.add_argument(*flags, action="store_true")
    args, rest = parser.parse_known_args(argv)
    ours = not (args.config_path or args.config_name or args.config_dir)
    return [a for a in rest if not a.startswith("-")], ours


def fail(err: Exception, status: int = BAD_INPUT) -> None:
    """Report bad input (or, with another `status`, a run that cannot go on) as one line and exit."""
    message = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    print(f"error: {message}", file=sys.stderr)
    sys.exit(status)


# Hydra plugins by the group option that selects them: the module, and the extra that installs it
PLUGINS = {
    "hydra/launcher": {
        "joblib": ("hydra_plugins.hydra_joblib_launcher", "joblib"),
        "ray": ("hydra_plugins.hydra_ray_launcher", "ray"),
        "ray_aws": ("hydra_plugins.hydra_ray_launcher", "ray"),
        "submitit_local": ("hydra_plugins.hydra_submitit_launcher", "submitit"),
        "submitit_slurm": ("hydra_plugins.hydra_submitit_launcher", "submitit"),
    },
    "hydra/sweeper": {"optuna": ("hydra_plugins.hydra_optuna_sweeper", "optuna")},
}


# What a launcher is given unless the command line says otherwise: joblib's loky workers wait 300 s
# for a next job, so an idle one would outlive a killed sweep by minutes; 2 s ends it with the sweep.
LAUNCHER_DEFAULTS = {"joblib": ("+hydra.launcher.idle_worker_timeout=2",)}


def with_launcher_defaults(argv: list[str]) -> list[str]:
    """`argv` with LAUNCHER_DEFAULTS for the launcher it names (none that it sets itself)."""
    overrides, _ = overrides_of(argv)
    given = {o.split("=", 1)[0].lstrip("+") for o in overrides}
    choice = dict(o.split("=", 1) for o in overrides if "=" in o).get("hydra/launcher")
    extra = [d for d in LAUNCHER_DEFAULTS.get(choice, ()) if d.split("=", 1)[0].lstrip("+") not in given]
    return [*argv, *extra]


def check_plugins(overrides: list[str]) -> None:
    """A launcher or sweeper whose extra is not installed, or a Ray cluster address that does not
    answer: one ValueError line, before Hydra starts anything."""
    import importlib.util

    values = dict(o.split("=", 1) for o in overrides if "=" in o)
    for group, options in PLUGINS.items():
        choice = values.get(group)
        if choice is not None and choice != "basic" and choice not in options:  # basic: Hydra's own
            raise ValueError(f"{group}={choice} names no {group.split('/')[1]}; available: basic, {', '.join(options)}")
        if choice in options:
            module, extra = options[choice]
            if importlib.util.find_spec(module) is None:
                raise ValueError(f'{group}={choice} needs the {extra} extra: pip install -e ".[{extra}]"')
    address = values.get("hydra.launcher.ray.init.address")
    if values.get("hydra/launcher") == "ray" and address not in (None, "null", "auto"):
        import socket

        host, _, port = address.rpartition(":")
        try:
            socket.create_connection((host, int(port)), timeout=3).close()
        except (OSError, ValueError):
            raise ValueError(
                f"no Ray cluster answers at hydra.launcher.ray.init.address={address}: start one with "
                f'`ray start --head --port={port or 6379}` (docs/training.md, "Sweeps on a Ray cluster")'
            ) from None


def precheck(config_name: str, argv: list[str] | None = None) -> list[str]:
    """Check the command line's overrides against the schema and conf/ before Hydra composes
    (bfc.config.check_overrides), and the launcher or sweeper they name (check_plugins): a key
    that names nothing, a moved key, an unknown group option, bad override syntax, a missing
    extra or a Ray cluster that does not answer ends here with one line, before any job of a
    sweep starts. Returns the arguments Hydra is to run: `env.airframe=<name or file>` expanded
    (bfc.config.expand_airframe)."""
    import warnings

    from bfc.config import check_overrides, expand_airframe
    from bfc.hydra_compat import skip_mode_probe

    # conf/hydra/launcher/ray.yaml replaces the Ray plugin's defaults, which Hydra warns of
    warnings.filterwarnings("ignore", message=r"\s*'hydra/launcher/ray' is validated against ConfigStore schema")
    argv = sys.argv[1:] if argv is None else list(argv)
    overrides, ours = overrides_of(argv)
    if not ours:
        return argv
    skip_mode_probe()  # the repository's configs never set hydra.mode: one composition, not two
    try:
        if config_name == "config":
            expanded = expand_airframe(overrides)
            if expanded != overrides:
                flags = [a for a in argv if a not in overrides]
                argv, overrides = [*flags, *expanded], expanded
        check_overrides(overrides, config_name)
        check_plugins(overrides)
    except ValueError as err:
        fail(err)
    return argv
