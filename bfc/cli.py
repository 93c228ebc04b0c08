"""What train.py and evaluate.py share: the command line checked before Hydra runs, and bad input
reported as one `error: ...` line with exit status 2 (never a traceback)."""

from __future__ import annotations

import argparse
import sys

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


def fail(err: Exception) -> None:
    """Report bad input as one line and exit with status 2."""
    message = str(err).strip().splitlines()[0] if str(err).strip() else type(err).__name__
    print(f"error: {message}", file=sys.stderr)
    sys.exit(2)


def precheck(config_name: str, argv: list[str] | None = None) -> None:
    """Check the command line's overrides against the schema and conf/ before Hydra composes
    (bfc.config.check_overrides): a key that names nothing, a moved key, an unknown group option
    or bad override syntax ends here with one line, before any job of a sweep starts."""
    from bfc.config import check_overrides

    overrides, ours = overrides_of(sys.argv[1:] if argv is None else argv)
    if not ours:
        return
    try:
        check_overrides(overrides, config_name)
    except ValueError as err:
        fail(err)
