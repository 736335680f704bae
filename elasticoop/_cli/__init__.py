"""The `elasticoop` command line: one small module per sub-command.

Each sub-command module defines `register(subparsers)`, which adds its parser and
sets `func` (called with the parsed arguments, returns the exit code). To add a
sub-command, write a module like `check.py` and list it in `COMMANDS` with its
one-line help.

Only the module of the command that runs is imported: `elasticoop --version` and
`elasticoop --help` import neither JAX nor the scientific stack, and `elasticoop
check` none of what simulating, plotting or fitting needs.
"""

import argparse
import contextlib
import importlib
import sys
from collections.abc import Sequence

# Each sub-command and the help line its module gives it (a test holds them equal),
# in the order `elasticoop --help` lists them.
COMMANDS = {
    "run": "simulate a scenario file and write results and plots",
    "check": "validate scenario and study files (no simulation)",
    "demo": "run the built-in scenario and print a summary (the default)",
    "examples": "list the example scenarios, or copy them to a folder",
    "modes": "static equilibrium, natural frequencies and mode shapes",
    "identify": "fit stiffness, damping, masses or inertias to measured motion",
    "montecarlo": "run a Monte Carlo study file, or summarise its results",
}
CACHED = ("run", "check", "demo", "modes", "identify")
DEFAULT = "demo"


def build_parser(commands: Sequence[str] | None = None) -> argparse.ArgumentParser:
    """The parser of the command line, with the full parsers of `commands` (default:
    all); each other command is listed with its help line only."""
    from .._version import __version__

    full = COMMANDS if commands is None else commands
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
    for name, help_line in COMMANDS.items():
        if name in full:
            importlib.import_module(f".{name}", __name__).register(subparsers)
        else:
            subparsers.add_parser(name, help=help_line, add_help=False)
    return parser


def _command_in(argv: Sequence[str]) -> str | None:
    """The command `argv` names: its first word that is not an option (the
    top-level options take no value)."""
    return next((word for word in argv if not word.startswith("-")), None)


def main(argv=None) -> int:
    """Entry point of the `elasticoop` console script and `python -m elasticoop`."""
    argv = sys.argv[1:] if argv is None else list(argv)
    command = _command_in(argv)
    try:
        args = build_parser([command] if command in COMMANDS else []).parse_args(argv)
        if args.command is None:  # no command, only options such as --debug
            args = build_parser([DEFAULT]).parse_args([*argv, DEFAULT])
    except SystemExit as exit_:  # --help, --version or a usage error
        return int(exit_.code or 0)
    from ._common import named_paths, report_user_errors

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
    from .._cache import compilation_cache
    from ._common import UserError

    try:
        stack.enter_context(compilation_cache())
    except (ValueError, OSError) as err:  # the folder is a file, or not writable
        raise UserError(
            f"cannot use the compilation cache folder ({err}); set "
            "ELASTICOOP_CACHE_DIR to a writable folder"
        ) from err
