"""`elasticoop demo` (also `python -m elasticoop`): the built-in scenario, the
main job."""

import dataclasses
import time

from .._examples import default_scenario
from .._io.summary import format_summary, scenario_summary
from ._common import (
    EXIT_OK,
    add_output_options,
    common_options,
    fraction,
    output_folder,
    positive_float,
    say,
    simulate_scenario,
    stopped_early,
    write_results,
)

NAME = "demo"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="run the built-in scenario and print a summary (the default)",
        description=(
            "Simulate the built-in scenario (two manipulators lift a beam through "
            "elastic grasps; the packaged example 'beam_lift') and print the "
            "object's displacement, the peak grasp forces and the energy balance. "
            "With -o, also write the results and plots as 'run' does."
        ),
    )
    parser.add_argument(
        "--rtol", type=fraction, default=None, help="relative tolerance, in (0, 1)"
    )
    parser.add_argument(
        "--atol", type=positive_float, default=None, help="absolute tolerance"
    )
    add_output_options(parser, "also write results and plots here")
    parser.set_defaults(func=execute)


def run_default(rtol: float = 1e-8, atol: float = 1e-10) -> dict:
    """Simulate `default_scenario()` and return its summary as a dict."""
    scenario = default_scenario()
    options = dataclasses.replace(scenario.options, rtol=rtol, atol=atol)
    scenario = dataclasses.replace(scenario, options=options)
    start = time.perf_counter()
    traj = scenario.simulate()
    traj.y.block_until_ready()
    return scenario_summary(scenario, traj, time.perf_counter() - start)


def execute(args) -> int:
    scenario = default_scenario()
    tolerances = {k: getattr(args, k) for k in ("rtol", "atol")}
    options = dataclasses.replace(
        scenario.options, **{k: v for k, v in tolerances.items() if v is not None}
    )
    scenario = dataclasses.replace(scenario, options=options)
    folder = None if args.output is None else output_folder(args)
    traj, wall, error = simulate_scenario(scenario, args)
    if folder is not None:
        paths = write_results(scenario, traj, wall, folder, args)
    if error is not None:
        raise stopped_early(scenario, error, folder)
    say(args, format_summary(scenario_summary(scenario, traj, wall)))
    if folder is not None:
        say(args, "wrote " + ", ".join(str(p) for p in paths))
    return EXIT_OK
