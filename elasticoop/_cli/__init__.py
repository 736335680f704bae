"""The `elasticoop` command line: one small module per sub-command.

Each sub-command module defines `register(subparsers)`, which adds its parser and
sets `func` (called with the parsed arguments, returns the exit code). To add a
sub-command, write a module like `check.py` and list it in `COMMANDS`.
"""

import argparse
import contextlib
import sys

from .._cache import compilation_cache
from . import check, demo, examples, modes, run
from ._common import EXIT_USAGE, report_user_errors

COMMANDS = (run, check, demo, examples, modes)
CACHED = ("run", "demo", "modes")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = argparse.ArgumentParser(
        prog="elasticoop",
        description=(
            "Simulate the elastic system of cooperative manipulation: m manipulators "
            "hold one object through elastic grasps. Describe a study in a TOML "
            "scenario file, check it, run it, and get the trajectory (netCDF, CSV), "
            "a JSON summary and plots. Without a command, runs the demo."
        ),
        epilog="Run 'elasticoop COMMAND --help' for the options of a command.",
    )
    parser.add_argument("--version", action="version", version=__version__)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.register(subparsers)
    return parser


def main(argv=None) -> int:
    """Entry point of the `elasticoop` console script and `python -m elasticoop`."""
    argv = sys.argv[1:] if argv is None else list(argv)
    if not argv:
        argv = ["demo"]
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
    except SystemExit as exit_:  # --help, --version or a usage error
        return int(exit_.code or 0)
    if args.command is None:
        parser.print_help()
        return EXIT_USAGE
    # Commands that compile simulations keep the executables on disk
    # ($ELASTICOOP_CACHE_DIR or ~/.cache/elasticoop/jax) for the next process.
    cache = compilation_cache() if args.command in CACHED else contextlib.nullcontext()
    with report_user_errors(args.command) as outcome, cache:
        outcome.code = args.func(args)
    return outcome.code
