"""`elasticoop run SCENARIO -o OUTDIR`: simulate a scenario file and write the
trajectory (netCDF, CSV), a JSON summary and plots."""

from .._io.summary import format_summary, scenario_summary
from ._common import (
    EXIT_OK,
    add_output_options,
    check_options,
    common_options,
    load,
    output_folder,
    say,
    simulate_scenario,
    stopped_early,
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
            "(and animation.gif/.mp4 with --animation; a plot that does not apply "
            "to the scenario, such as elastic_wrench.png for a body on its own, is "
            "skipped). The files are written into a new folder beside OUTDIR, "
            "which takes OUTDIR's place once they are all written: an interrupted "
            "run leaves OUTDIR as it was. OUTDIR must be missing or empty, or "
            "hold an earlier run's results with --overwrite (then it is replaced "
            "as a whole). Exit code 0 on success, 2 for an invalid scenario or an "
            "unusable OUTDIR (checked before simulating), 3 when the simulation "
            "stops early (the partial results are still written)."
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO", help="TOML scenario file")
    add_output_options(parser, "folder for results", required=True)
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
    check_options(scenario, args)
    folder = output_folder(args, args.scenario)
    say(args, f"elasticoop run: {scenario.name} ({args.scenario})")
    traj, wall, error = simulate_scenario(scenario, args)
    paths = write_results(scenario, traj, wall, folder, args)
    if error is not None:
        raise stopped_early(scenario, error, folder)
    say(args, format_summary(scenario_summary(scenario, traj, wall)))
    say(args, "wrote " + ", ".join(str(p) for p in paths))
    return EXIT_OK
