"""The `elasticoop` command line: one small module per sub-command.

Each sub-command module defines `register(subparsers)`, which adds its parser and
sets `func` (called with the parsed arguments, returns the exit code). To add a
sub-command, write a module like `check.py` and list it in `COMMANDS`.
"""

import argparse
import contextlib
import sys

from .._cache import compilation_cache
from . import check, demo, examples, identify, modes, montecarlo, run
from ._common import UserError, named_paths, report_user_errors

COMMANDS = (run, check, demo, examples, modes, identify, montecarlo)
CACHED = ("run", "demo", "modes", "identify")


def build_parser() -> argparse.ArgumentParser:
    from .._version import __version__

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
    parser.add_argument(
        "--debug",
        action="store_true",
        help="show the full traceback of every error (give it before COMMAND)",
    )
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for command in COMMANDS:
        command.register(subparsers)
    return parser


def main(argv=None) -> int:
    """Entry point of the `elasticoop` console script and `python -m elasticoop`."""
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = build_parser()
    try:
        args = parser.parse_args(argv)
        if args.command is None:  # no command, only options such as --debug
            args = parser.parse_args([*argv, "demo"])
    except SystemExit as exit_:  # --help, --version or a usage error
        return int(exit_.code or 0)
    with (
        report_user_errors(
            args.command, debug=args.debug, paths=named_paths(args)
        ) as outcome,
        contextlib.ExitStack() as stack,
    ):
        if args.command in CACHED:
            _use_compilation_cache(stack)
        outcome.code = args.func(args)
    return outcome.code


def _use_compilation_cache(stack: contextlib.ExitStack) -> None:
    """Keep the compiled executables on disk ($ELASTICOOP_CACHE_DIR or
    ~/.cache/elasticoop/jax) for the next process, until `stack` closes."""
    try:
        stack.enter_context(compilation_cache())
    except (ValueError, OSError) as err:  # the folder is a file, or not writable
        raise UserError(
            f"cannot use the compilation cache folder ({err}); set "
            "ELASTICOOP_CACHE_DIR to a writable folder"
        ) from err
