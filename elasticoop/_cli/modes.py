"""`elasticoop modes SCENARIO`: static equilibrium, linearization and modes."""

import numpy as np

from .._analysis import linearize, modes, static_equilibrium
from .._forces import ConstantForce
from .._io.strict_json import strict_json
from .._plotting import plot_mode_shapes
from ._common import (
    EXIT_OK,
    UserError,
    add_output_options,
    common_options,
    load,
    output_folder,
    positive_int,
    say,
)

NAME = "modes"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="static equilibrium, natural frequencies and mode shapes",
        description=(
            "Find the static equilibrium of a scenario under gravity and its "
            "constant contact forces, with the coordinates of its [prescribed] table "
            "held at their initial values (without one: every coordinate of the "
            "contact bodies is held), starting from the initial state; then "
            "linearize there and print the natural frequencies, damping ratios and "
            "dominant coordinates of the modes. With -o, also write modes.json "
            "(strict JSON: a damping ratio that does not apply is null; the mass-"
            "normalized mode shapes as 'shapes', a row per free coordinate and a "
            "column per mode, as 'shapes_dims' says) and a plot "
            "of the first mode shapes, modes.png, into a new folder that takes "
            "OUTDIR's place once both are written (OUTDIR must be missing or "
            "empty, or hold earlier results with --overwrite)."
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO", help="TOML scenario file")
    add_output_options(parser, "write modes.json and modes.png here")
    parser.add_argument(
        "--count", type=positive_int, default=4, help="mode shapes to plot (default 4)"
    )
    parser.set_defaults(func=execute)


def execute(args) -> int:
    scenario = load(args.scenario)
    folder = None if args.output is None else output_folder(args, args.scenario)
    forces = None
    if isinstance(scenario.forces, ConstantForce):
        forces = np.asarray(scenario.forces.F)
    elif scenario.forces is not None:
        say(
            args,
            f"note: the scenario's {type(scenario.forces).__name__} forces are not "
            "constant; the equilibrium is found without them",
        )
    if scenario.prescribed is not None:
        mask = scenario.prescribed.mask
    else:
        mask = np.zeros((scenario.model.n_bodies, 6), bool)
        mask[1:] = True
        say(args, "no [prescribed] table: the contact bodies are held")
    try:
        eq = static_equilibrium(scenario.model, scenario.y_init, mask, forces)
        result = modes(linearize(scenario.model, eq.y, mask, scenario.names))
    except ValueError as err:  # the scenario has no unique, stable equilibrium
        raise UserError(f"{args.scenario}: {err}") from err
    say(
        args,
        f"{args.scenario}: static equilibrium found in {eq.steps} iterations "
        f"(largest force imbalance {float(eq.residual):.2e}); "
        f"{'stable' if eq.stable else 'not stable'}",
        result.table(),
    )
    if folder is not None:
        summary = {
            "scenario": scenario.name,
            "equilibrium": np.asarray(eq.y).tolist(),
            "frequencies_hz": result.frequencies_hz.tolist(),
            "damping_ratios": result.damping_ratios.tolist(),
            "coordinates": list(result.names),
            # shapes[c][k]: mode k's component along coordinate c
            "shapes_dims": ["coordinate", "mode"],
            "shapes": result.shapes.tolist(),
        }
        with folder.writing() as staging:
            (staging / "modes.json").write_text(strict_json(summary))
            fig = plot_mode_shapes(result, count=args.count)
            fig.savefig(staging / "modes.png", dpi=120)
        say(args, f"wrote {folder.path / 'modes.json'} and {folder.path / 'modes.png'}")
    return EXIT_OK
