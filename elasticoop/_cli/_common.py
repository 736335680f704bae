"""What the sub-commands share: error reporting, --quiet, progress, output files."""

import argparse
import contextlib
import inspect
import sys
import time

from .._config import ScenarioError, load_scenario
from .._simulate import SimulationError, simulate

EXIT_OK = 0
EXIT_USAGE = 2  # bad arguments or an invalid scenario file
EXIT_SIMULATION = 3  # the simulation stopped early (gimbal lock, collapsed link, ...)


class _Outcome:
    code = EXIT_OK


@contextlib.contextmanager
def report_user_errors(command: str):
    """Turn user errors into a one-paragraph message on stderr and an exit code
    (no traceback): invalid scenarios and arguments give 2, simulation failures 3.
    Anything else is a bug in elasticoop and keeps its traceback."""
    outcome = _Outcome()
    try:
        yield outcome
    except ScenarioError as err:
        print(f"elasticoop {command}: error: {err}", file=sys.stderr)
        outcome.code = EXIT_USAGE
    except SimulationError as err:
        print(f"elasticoop {command}: simulation stopped early: {err}", file=sys.stderr)
        outcome.code = EXIT_SIMULATION
    except (ValueError, OSError) as err:
        print(f"elasticoop {command}: error: {err}", file=sys.stderr)
        outcome.code = EXIT_USAGE
    except KeyboardInterrupt:
        print(f"elasticoop {command}: interrupted", file=sys.stderr)
        outcome.code = 130


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


def progress_overrides(args) -> dict:
    """A tqdm progress bar for the solve (`diffrax.TqdmProgressMeter`, drawn on
    stderr through host callbacks) when not quiet, stderr is a terminal, and
    `simulate` accepts a `progress_meter`."""
    if args.quiet or not sys.stderr.isatty():
        return {}
    if "progress_meter" not in inspect.signature(simulate).parameters:
        return {}
    import diffrax

    return {"progress_meter": diffrax.TqdmProgressMeter()}


def simulate_scenario(scenario, args):
    """Run a scenario; returns `(trajectory, wall time [s], error or None)`. A
    `SimulationError` is returned with its partial trajectory, not raised."""
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


def write_results(scenario, traj, wall_time, outdir, args) -> list:
    """Write netCDF, CSV, JSON summary and (unless `--no-plots`) PNG plots and an
    optional animation for one run; returns the paths written."""
    from .._export import scenario_summary, trajectory_to_xarray, write_outputs

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
    )
    summary = scenario_summary(scenario, traj, wall_time)
    paths = list(write_outputs(ds, summary, outdir).values())
    if not getattr(args, "no_plots", False):
        paths += write_plots(scenario, traj, outdir, args)
    return paths


def write_plots(scenario, traj, outdir, args) -> list:
    import pathlib

    from .. import _plotting as plots

    outdir = pathlib.Path(outdir)
    figures = {
        "coordinates.png": plots.plot_coordinates(traj, scenario.names),
        "elastic_wrench.png": plots.plot_elastic_wrench(
            traj, scenario.connection_names or None, scenario.names
        ),
        "energy.png": plots.plot_energy(traj),
        "snapshots.png": plots.plot_snapshots(
            traj, times=getattr(args, "snapshots", None), body_names=scenario.names
        ),
    }
    paths = []
    for name, fig in figures.items():
        fig.savefig(outdir / name, dpi=110)
        paths.append(outdir / name)
    animation = getattr(args, "animation", None)
    if animation:
        from matplotlib import animation as mpl_animation

        if animation == "mp4" and not mpl_animation.writers.is_available("ffmpeg"):
            say(args, "  ffmpeg not found: writing the animation as GIF instead of MP4")
            animation = "gif"
        paths.append(
            plots.save_animation(
                traj, outdir / f"animation.{animation}", scenario.names
            )
        )
    return paths
