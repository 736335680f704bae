"""What the sub-commands share: error reporting, --quiet, progress, output files."""

import argparse
import contextlib
import inspect
import math
import os
import pathlib
import sys
import time
import traceback

import numpy as np

from .._config import ScenarioError, load_scenario
from .._config.limits import format_bytes, run_files_bytes
from .._io.folder import OutputFolder, OutputFolderError
from .._status import status_message
from .._trajectory import SimulationError

EXIT_OK = 0
EXIT_BUG = 1  # a bug in elasticoop (or a dependency): shown with its traceback
EXIT_USAGE = 2  # bad arguments, an invalid scenario file, a file that cannot be used
EXIT_SIMULATION = 3  # the simulation stopped early (gimbal lock, collapsed link, ...)

# The arguments, over all sub-commands, that name files or folders: an `OSError`
# about one of them (or about a file inside or a folder above one) is the user's.
PATH_ARGUMENTS = ("scenario", "scenarios", "data", "output", "copy")


class UserError(Exception):
    """A problem with what the user asked for that argparse cannot check (e.g. an
    option value that only makes sense for a given scenario). Sub-commands raise
    it with a message for the user: reported as `elasticoop COMMAND: error:
    MESSAGE`, exit code 2, no traceback."""


def positive_float(text: str) -> float:
    """argparse `type` for a finite number > 0."""
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not a number: {text!r}") from None
    if not (math.isfinite(value) and value > 0):
        raise argparse.ArgumentTypeError(f"must be a positive number, got {text!r}")
    return value


def fraction(text: str) -> float:
    """argparse `type` for a number in (0, 1) (a relative tolerance)."""
    value = positive_float(text)
    if not value < 1:
        raise argparse.ArgumentTypeError(f"must be below 1, got {text!r}")
    return value


def positive_int(text: str) -> int:
    """argparse `type` for an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"not an integer: {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be at least 1, got {text!r}")
    return value


def named_paths(args) -> list[pathlib.Path]:
    """The files and folders named on the command line (`PATH_ARGUMENTS`)."""
    paths = []
    for name in PATH_ARGUMENTS:
        value = getattr(args, name, None)
        for item in value if isinstance(value, list | tuple) else [value]:
            if isinstance(item, str | os.PathLike) and str(item):
                paths.append(_absolute(item))
    return paths


def _absolute(path) -> pathlib.Path:
    return pathlib.Path(os.path.abspath(os.path.expanduser(os.fsdecode(path))))


def _about_named_path(err: OSError, paths) -> bool:
    """Whether `err` is about a file or folder named on the command line, a file
    inside one, or a folder above one (`mkdir` of an output folder's parents)."""
    for name in (err.filename, err.filename2):
        if not isinstance(name, str | bytes | os.PathLike) or not os.fsdecode(name):
            continue
        path = _absolute(name)
        for given in paths:
            if path == given or given in path.parents or path in given.parents:
                return True
    return False


class _Outcome:
    code = EXIT_OK


@contextlib.contextmanager
def report_user_errors(command: str, *, debug: bool = False, paths=()):
    """Turn the user's errors into a one-paragraph message on stderr and an exit
    code, without a traceback: an invalid scenario, a `UserError`, or an `OSError`
    about one of `paths` (the files and folders the user named) gives 2, a
    simulation that stops early 3. Anything else is a bug in elasticoop: its
    traceback is shown, and the exit code is 1. With `debug`, every error shows
    its traceback."""
    outcome = _Outcome()
    prefix = f"elasticoop {command}"

    def report(message: str, code: int) -> None:
        if debug:
            traceback.print_exc()
        print(f"{prefix}: {message}", file=sys.stderr)
        outcome.code = code

    try:
        yield outcome
    except (ScenarioError, UserError, OutputFolderError) as err:
        report(f"error: {err}", EXIT_USAGE)
    except SimulationError as err:
        report(f"simulation stopped early: {err}", EXIT_SIMULATION)
    except OSError as err:
        if _about_named_path(err, paths):
            report(f"error: {err}", EXIT_USAGE)
        else:
            _report_bug(prefix, outcome)
    except KeyboardInterrupt:
        report("interrupted", 130)
    except Exception:
        _report_bug(prefix, outcome)


def _report_bug(prefix: str, outcome: _Outcome) -> None:
    traceback.print_exc()
    err = sys.exc_info()[1]
    print(
        f"{prefix}: internal error ({type(err).__name__}: {err}). This is a bug in "
        "elasticoop, not a problem with your input: please report it with the "
        "traceback above.",
        file=sys.stderr,
    )
    outcome.code = EXIT_BUG


def common_options() -> argparse.ArgumentParser:
    """Options every sub-command takes (use as a parent parser)."""
    parent = argparse.ArgumentParser(add_help=False)
    parent.add_argument(
        "-q",
        "--quiet",
        action="store_true",
        help="print nothing but errors (no summary, no progress bar)",
    )
    return parent


def say(args, *lines) -> None:
    if not args.quiet:
        print(*lines, sep="\n")


def shows_progress(args) -> bool:
    """Whether to draw a progress bar: not quiet, and stderr is a terminal (a bar
    written to a file or a pipe is a line per update)."""
    return not args.quiet and sys.stderr.isatty()


def progress_overrides(args) -> dict:
    """A tqdm progress bar for the solve (`diffrax.TqdmProgressMeter`, drawn on
    stderr through host callbacks) when `shows_progress` and `simulate` accepts a
    `progress_meter`."""
    if not shows_progress(args):
        return {}
    from .._simulate import simulate

    if "progress_meter" not in inspect.signature(simulate).parameters:
        return {}
    import diffrax

    return {"progress_meter": diffrax.TqdmProgressMeter()}


def check_options(scenario, args) -> None:
    """Raise `UserError` for options that do not fit the scenario: `--snapshots`
    instants outside its time span (when plots are drawn)."""
    times = getattr(args, "snapshots", None)
    if not times or getattr(args, "no_plots", False):
        return
    t0, t1 = (float(t) for t in np.asarray(scenario.ts)[[0, -1]])
    outside = [t for t in times if not t0 <= t <= t1]
    if outside:
        raise UserError(
            f"--snapshots: {', '.join(f'{t:g} s' for t in outside)} "
            f"{'lies' if len(outside) == 1 else 'lie'} outside the scenario's time "
            f"span, {t0:g} to {t1:g} s"
        )


def simulate_scenario(scenario, args):
    """Check the options against the scenario (`check_options`), then run it;
    returns `(trajectory, wall time [s], error or None)`. A `SimulationError` is
    returned with its partial trajectory, not raised. With an output folder,
    its free space is checked first (`check_free_space`)."""
    check_options(scenario, args)
    check_free_space(scenario, args)
    start = time.perf_counter()
    try:
        traj = scenario.simulate(**progress_overrides(args))
        traj.y.block_until_ready()
        error = None
    except SimulationError as err:
        traj, error = err.trajectory, err
    return traj, time.perf_counter() - start, error


def load(path):
    return load_scenario(path)


def stopped_early(scenario, error: SimulationError, folder=None) -> SimulationError:
    """The `SimulationError` of a run that stopped early, reworded for the command
    line: the body or connection at fault by the scenario's names, and where the
    partial results were written (`folder`, an `OutputFolder`, or `None` when none
    were)."""
    traj = error.trajectory
    message = status_message(traj, scenario.names, scenario.connection_names or None)
    t0, t = float(traj.ts[0]), float(traj.event_time)
    if folder is None:
        where = "no results were written (give -o OUTDIR to keep the partial ones)"
    else:
        where = (
            f"the partial results, from t = {t0:g} to {t:g} s (NaN after), were "
            f"written to {folder.path}"
        )
    return SimulationError(f"{message}; {where}", traj)


def add_output_options(parser, help: str, required: bool = False) -> None:
    """`-o/--output OUTDIR` and `--overwrite` (see `output_folder`)."""
    parser.add_argument(
        "-o", "--output", metavar="OUTDIR", required=required, help=help
    )
    parser.add_argument(
        "--overwrite",
        action="store_true",
        help="replace OUTDIR if it holds the results of an earlier run (without "
        "it, a folder that is not empty is refused)",
    )


def output_folder(args, scenario_file: str | None = None) -> OutputFolder:
    """The checked output folder of `-o`, before any work. What an interrupted
    earlier write left beside it is put right first (`OutputFolder.recover`: the
    folder restored, the leftovers removed), with a note on stderr. Raises
    `OutputFolderError` when it is a file, not empty (without `--overwrite`), is
    or holds the scenario file or the current folder, or cannot be created."""
    keep = {os.getcwd(): "the current folder"}
    if scenario_file:
        keep[scenario_file] = "the scenario file"
    folder = OutputFolder.of(args.output, overwrite=args.overwrite, keep=keep)
    for note in folder.recover():
        print(f"elasticoop {args.command}: note: {note}", file=sys.stderr)
    folder.check()
    return folder


def check_free_space(scenario, args) -> None:
    """Raise `OutputFolderError` before simulating when the file system of the
    output folder (`-o`, if given) has less free space than the files of the run
    may take at most (`limits.run_files_bytes`; the previous results are removed
    only once the new ones are in place, so they do not count as free)."""
    from .._io.files import free_bytes

    if not getattr(args, "output", None):
        return
    folder = OutputFolder.of(args.output)

    plots = not getattr(args, "no_plots", False)
    sizes = run_files_bytes(
        int(np.asarray(scenario.ts).size),
        scenario.model.n_bodies,
        len(scenario.connection_names),
        scenario.prescribed is not None,
        plots,
    )
    needed = sum(sizes.values())
    free = free_bytes(folder.path.parent)
    if needed > free:
        parts = ", ".join(
            f"{name} {format_bytes(size)}" for name, size in sizes.items()
        )
        raise OutputFolderError(
            f"not enough free space for the results in {folder.path}: the run "
            f"writes up to {format_bytes(needed)} ({parts}) and "
            f"{format_bytes(free)} are free; free some space, choose a folder on "
            "another disk, or ask for fewer [time] samples"
        )


def write_results(scenario, traj, wall_time, folder: OutputFolder, args) -> list:
    """Write netCDF, CSV, JSON summary and (unless `--no-plots`) PNG plots and an
    optional animation for one run into `folder`, as a whole (see
    `OutputFolder.writing`); returns the paths written."""
    from .._io.files import write_outputs
    from .._io.summary import scenario_summary
    from .._io.xarray import trajectory_to_xarray

    ds = trajectory_to_xarray(
        traj,
        body_names=scenario.names,
        connection_names=scenario.connection_names or None,
        attrs={
            "scenario": scenario.name,
            "scenario_file": str(scenario.source or ""),
            "solver": scenario.solver,
            "rtol": scenario.rtol,
            "atol": scenario.atol,
        },
        forces=scenario.forces,
    )
    summary = scenario_summary(scenario, traj, wall_time)
    with folder.writing() as staging:
        paths = list(write_outputs(ds, summary, staging).values())
        if not getattr(args, "no_plots", False):
            paths += write_plots(scenario, traj, staging, args)
    return [folder.path / pathlib.Path(p).name for p in paths]


def inapplicable_plots(traj) -> dict[str, str]:
    """The plots that do not apply to a run, with the reason."""
    from .._plotting import elastic_load_count

    if elastic_load_count(traj) == 0:
        return {"elastic_wrench.png": "the model has no connections or contact bodies"}
    return {}


def write_plots(scenario, traj, outdir, args) -> list:
    """Draw the plots that apply to the run (see `inapplicable_plots`; those
    skipped are named unless `--quiet`) into `outdir`; returns the paths."""
    from .._plotting import (
        plot_coordinates,
        plot_elastic_wrench,
        plot_energy,
        plot_snapshots,
        save_animation,
    )

    outdir = pathlib.Path(outdir)
    draw = {
        "coordinates.png": lambda: plot_coordinates(traj, scenario.names),
        "elastic_wrench.png": lambda: plot_elastic_wrench(
            traj, scenario.connection_names or None, scenario.names
        ),
        "energy.png": lambda: plot_energy(traj),
        "snapshots.png": lambda: plot_snapshots(
            traj, times=getattr(args, "snapshots", None), body_names=scenario.names
        ),
    }
    skipped = inapplicable_plots(traj)
    paths = []
    for name, figure in draw.items():
        if name in skipped:
            say(args, f"  skipped {name}: {skipped[name]}")
            continue
        figure().savefig(outdir / name, dpi=110)
        paths.append(outdir / name)
    animation = getattr(args, "animation", None)
    if animation:
        from matplotlib import animation as mpl_animation

        if animation == "mp4" and not mpl_animation.writers.is_available("ffmpeg"):
            say(args, "  ffmpeg not found: writing the animation as GIF instead of MP4")
            animation = "gif"
        paths.append(
            save_animation(traj, outdir / f"animation.{animation}", scenario.names)
        )
    return paths


def write_text_atomic(file: pathlib.Path, text: str) -> None:
    """Write `text` to `file` through a temporary file and a rename, so that a
    failed write (a full disk, a read-only folder) leaves the earlier file whole;
    `UserError` naming the file on failure."""
    tmp = file.with_name(f".{file.name}.{os.getpid()}.tmp")
    try:
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, file)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise UserError(
            f"cannot write {file}: {err.strerror or err} [errno {err.errno}]; the "
            f"results stored so far are kept"
        ) from err
