"""`elasticoop run SCENARIO -o OUTDIR`: simulate a scenario file and write the
trajectory (netCDF, CSV), a JSON summary and plots."""

from .._io.summary import format_summary, scenario_summary
from ._common import (
    EXIT_OK,
    common_options,
    load,
    say,
    simulate_scenario,
    write_results,
)

NAME = "run"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="simulate a scenario file and write results and plots",
        description=(
            "Simulate the scenario file SCENARIO and write into OUTDIR: "
            "trajectory.nc (xarray/netCDF: dims time, body, coordinate), "
            "trajectory.csv (one column per quantity), summary.json, and the plots "
            "coordinates.png, elastic_wrench.png, energy.png, snapshots.png "
            "(and animation.gif/.mp4 with --animation). Exit code 0 on success, 2 "
            "for an invalid scenario, 3 when the simulation stops early (the "
            "partial results are still written)."
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO", help="TOML scenario file")
    parser.add_argument(
        "-o", "--output", metavar="OUTDIR", required=True, help="folder for results"
    )
    parser.add_argument(
        "--no-plots", action="store_true", help="write data files only, no PNGs"
    )
    parser.add_argument(
        "--snapshots",
        metavar="T",
        type=float,
        nargs="+",
        help="instants [s] of the 3-D view (default: 4 evenly spaced)",
    )
    parser.add_argument(
        "--animation",
        choices=("gif", "mp4"),
        help="also write a 3-D animation (mp4 needs ffmpeg, else GIF is written)",
    )
    parser.set_defaults(func=execute)


def execute(args) -> int:
    scenario = load(args.scenario)
    say(args, f"elasticoop run: {scenario.name} ({args.scenario})")
    traj, wall, error = simulate_scenario(scenario, args)
    paths = write_results(scenario, traj, wall, args.output, args)
    if error is not None:
        raise error
    say(args, format_summary(scenario_summary(scenario, traj, wall)))
    say(args, "wrote " + ", ".join(str(p) for p in paths))
    return EXIT_OK
