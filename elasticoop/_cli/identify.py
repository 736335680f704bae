"""`elasticoop identify SCENARIO DATA... -o OUTDIR`: fit a scenario's stiffness,
damping, masses or inertias to measured motion and write the fitted scenario
file, a report (text and JSON) and plots."""

import dataclasses
import datetime
import pathlib
import re
import sys
from collections.abc import Sequence

import numpy as np

from .._config import DataFileError, load_experiment
from .._config.identify_settings import (
    FitSelection,
    derived_feedforward,
    fit_selection,
    identify_spec_problems,
)
from .._config.schema import FITTED_QUANTITIES, IDENTIFY_METHODS, INITIAL_RULES
from .._identify import identify
from .._io.fitted_scenario import fitted_scenario_text
from .._io.strict_json import strict_json
from .._models import MobileModel
from .._scenario import IdentifySpec
from .._simulate import simulate
from ._common import (
    EXIT_OK,
    EXIT_SIMULATION,
    UserError,
    add_output_options,
    common_options,
    load,
    output_folder,
    positive_int,
    say,
)

NAME = "identify"
# The fit ended where the model does not explain the data (status "misfit").
EXIT_MISFIT = 4
_START_FAILURE = "the simulation at the starting parameters fails"
_SENSITIVITY_FAILURE = "the simulation with sensitivities fails at the start"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="fit stiffness, damping, masses or inertias to measured motion",
        description=(
            "Fit the parameters of the scenario file SCENARIO to the measured "
            "motion in the data files DATA (CSV or netCDF, see the data-file "
            "format) by output error, and write into OUTDIR: fitted_scenario.toml "
            "(the scenario with the fitted values, ready for 'elasticoop run'), "
            "report.txt and report.json (estimates, standard errors, "
            "identifiability flags, correlations, how the fit went), "
            "loss_history.png and one fit_<k>.png per data file (measured against "
            "fitted motion per coordinate). What is fitted comes from the "
            "scenario's [identify] table; the options below override its keys. "
            "OUTDIR is written as a whole, as for 'run'. Exit code 0 when the fit "
            "ends (the report says whether it converged), 2 for an invalid "
            "scenario, data file, option or OUTDIR (checked before fitting), 3 when "
            "the simulation fails at the start or every trial of the fit failed."
        ),
    )
    parser.add_argument("scenario", metavar="SCENARIO", help="TOML scenario file")
    parser.add_argument(
        "data", metavar="DATA", nargs="+", help="measured data files (.csv or .nc)"
    )
    add_output_options(parser, "folder for the results", required=True)
    parser.add_argument(
        "--fit",
        nargs="+",
        choices=FITTED_QUANTITIES,
        help="the quantities to fit (default: [identify] fit, else stiffness and "
        "damping)",
    )
    parser.add_argument(
        "--connections",
        nargs="+",
        metavar="NAME",
        help="fit stiffness and damping of these connections only (default: all)",
    )
    parser.add_argument(
        "--axes",
        nargs="+",
        metavar="AXIS",
        help="fit stiffness and damping along these axes only, e.g. x y z "
        "(default: all six)",
    )
    parser.add_argument(
        "--bodies",
        nargs="+",
        metavar="NAME",
        help="fit mass and inertia of these bodies only (default: all)",
    )
    parser.add_argument(
        "--max-iterations",
        type=positive_int,
        metavar="N",
        help="the most optimiser steps (default: [identify] max_iterations, else 100)",
    )
    parser.add_argument("--method", choices=IDENTIFY_METHODS, help="the optimiser")
    parser.add_argument(
        "--init",
        choices=("equation_error", "model"),
        help="start from the equation-error estimate when it fits better "
        "(equation_error, the default) or from the scenario's values (model)",
    )
    parser.add_argument(
        "--initial",
        choices=INITIAL_RULES,
        help="how each data file's initial state is set: equilibrium (at rest in "
        "the static equilibrium of the parameters evaluated, recomputed at every "
        'step of the fit; the default for [initial] from = "equilibrium"), '
        "frozen (the scenario's initial state as it is; the default otherwise), "
        "data (the first samples) or fitted (estimated with the parameters)",
    )
    parser.add_argument(
        "--feedforward",
        choices=("auto", "frozen", "rest"),
        help="a pose tracking's feedforward during the fit: frozen (the numbers of "
        'the scenario as given, e.g. "hold" of its nominal model), rest (the force '
        "that holds the grasps in the rest state of the parameters evaluated, "
        "recomputed with it; with --initial equilibrium), or auto (the default: "
        'frozen; where a feedforward = "hold" frozen so leaves a misfit, the fit '
        "is made again with rest and kept when it explains the data)",
    )
    parser.add_argument(
        "--no-velocities",
        action="store_true",
        help="ignore the velocity samples of the data files",
    )
    parser.add_argument("--no-plots", action="store_true", help="write no PNG files")
    parser.set_defaults(func=execute)


def fit_settings(scenario, args) -> IdentifySpec:
    """The scenario's `[identify]` settings with the command-line options applied;
    raises `UserError` naming an option whose names the scenario does not have."""
    spec = scenario.identify or IdentifySpec()
    overrides = {
        "fit": args.fit,
        "connections": args.connections,
        "axes": args.axes,
        "bodies": args.bodies,
        "max_iterations": args.max_iterations,
        "method": args.method,
        "init": args.init,
        "initial": args.initial,
        "feedforward": args.feedforward,
    }
    given = {k: v for k, v in overrides.items() if v is not None}
    spec = dataclasses.replace(
        spec, **{k: tuple(v) if isinstance(v, list) else v for k, v in given.items()}
    )
    kind = "mobile" if isinstance(scenario.model, MobileModel) else "immobile"
    problems = identify_spec_problems(
        spec,
        kind,
        scenario.model.convention,
        scenario.names,
        scenario.connection_names,
        check_applicable=False,
    )
    if problems:
        origin = {k: f"--{k.replace('_', '-')}" for k in given}
        # a key neither given nor in the file holds the default
        default = "the default" if scenario.identify is None else "[identify]"
        raise UserError(
            "; ".join(
                f"{origin.get(key, f'{default} {key}')}: {message}"
                + (
                    " (the scenario has no [identify] table: choose what to fit "
                    "with --fit)"
                    if key not in origin and scenario.identify is None
                    else ""
                )
                for key, message in problems
            )
        )
    return spec


def initial_rule_of(scenario, spec: IdentifySpec) -> str:
    """The initial-state rule of the fit: `spec.initial`, else `"equilibrium"` for
    a scenario that starts from its equilibrium and `"frozen"` otherwise."""
    if spec.initial is not None:
        return spec.initial
    if getattr(scenario, "initial_from", None) == "equilibrium":
        return "equilibrium"
    return "frozen"


def load_data(scenario, args) -> list:
    """One `Experiment` per data file; the problems of every file at once."""
    experiments, errors = [], []
    for path in args.data:
        try:
            experiments.append(
                load_experiment(path, scenario, velocities=not args.no_velocities)
            )
        except DataFileError as err:
            errors.append(err)
    if len(errors) == 1:
        raise errors[0]
    if errors:
        raise UserError("\n".join(str(e) for e in errors))
    with_noise = [p for p, e in zip(args.data, experiments) if e.sigma is not None]
    if with_noise and len(with_noise) != len(experiments):
        without = [p for p in args.data if p not in with_noise]
        raise UserError(
            f"noise levels (a 'sigma' row) are given in {', '.join(with_noise)} but "
            f"not in {', '.join(without)}: give them in every data file or in none"
        )
    return experiments


def execute(args) -> int:
    scenario = load(args.scenario)
    spec = fit_settings(scenario, args)
    selection = fit_selection(scenario, spec)
    folder = output_folder(args, args.scenario)
    experiments = load_data(scenario, args)
    say(
        args,
        f"elasticoop identify: {scenario.name} ({args.scenario}), "
        f"{len(selection.names)} parameters from {len(experiments)} data file"
        f"{'s' if len(experiments) != 1 else ''}",
    )
    initial = initial_rule_of(scenario, spec)
    rule = derived_feedforward(scenario)
    feedforward = "frozen" if spec.feedforward == "auto" else spec.feedforward
    try:
        result = _fit(
            scenario, experiments, selection, spec, args, initial, feedforward
        )
        if (
            spec.feedforward == "auto"
            and rule == "hold"
            and initial == "equilibrium"
            and result.status == "misfit"
        ):
            say(
                args,
                'the feedforward = "hold" of the nominal model, frozen, leaves a '
                "misfit: fitting again with the grasps held at rest by the force "
                "that holds them (--feedforward rest)",
            )
            held = _fit(scenario, experiments, selection, spec, args, initial, "rest")
            if held.status != "misfit":
                frozen_reason = result.reason
                result, feedforward = held, "rest"
                result = dataclasses.replace(
                    result,
                    notes=(
                        *result.notes,
                        'feedforward = "hold" taken as the force that held the '
                        "grasps at rest at the start (recomputed with the "
                        "parameters): with the nominal model's numbers frozen the "
                        f"model did not explain the data ({frozen_reason})",
                    ),
                )
    except ValueError as err:
        if str(err).startswith(_START_FAILURE) or str(err).startswith(
            _SENSITIVITY_FAILURE
        ):
            files = ", ".join(args.data)
            print(f"elasticoop {NAME}: {err} (data files: {files})", file=sys.stderr)
            return EXIT_SIMULATION
        raise UserError(str(err)) from err
    notes = [renamed(note, result.names, selection.names) for note in result.notes]
    if rule is not None and feedforward == "frozen":
        numbers = np.asarray(scenario.forces.feedforward)
        notes.append(
            f'the pose tracking\'s feedforward = "{rule}" is what the experimenter '
            f"applied: frozen as the numbers of the scenario as given (its nominal "
            f"model), not recomputed with the parameters; translational parts "
            + "; ".join(
                f"{name} {np.array2string(row[:3], precision=4)} N"
                for name, row in zip(scenario.names[1:], numbers)
            )
        )
    result = dataclasses.replace(result, names=selection.names, notes=tuple(notes))
    paths = write_results(
        scenario,
        experiments,
        result,
        selection,
        folder,
        args,
        initial,
        feedforward,
    )
    say(args, result.report())
    say(args, "wrote " + ", ".join(str(p) for p in paths))
    if result.status == "failed":
        print(f"elasticoop {NAME}: the fit failed: {result.reason}", file=sys.stderr)
        return EXIT_SIMULATION
    if result.status == "misfit":
        print(f"elasticoop {NAME}: misfit: {result.reason}", file=sys.stderr)
        return EXIT_MISFIT
    return EXIT_OK


def _fit(scenario, experiments, selection, spec, args, initial, feedforward):
    """`identify` with the scenario's settings and one feedforward rule."""
    return identify(
        scenario.model,
        experiments,
        selection.where,
        mask=selection.mask,
        method=spec.method,
        init=spec.init,
        max_iterations=spec.max_iterations,
        progress=not args.quiet,
        options=scenario.options,
        initial=initial,
        feedforward=feedforward,
        body_names=scenario.names,
    )


def report_data(
    scenario,
    result,
    selection: FitSelection,
    data_files,
    initial="frozen",
    feedforward="frozen",
) -> dict:
    """The report as a dictionary (written as `report.json`)."""
    unc = result.uncertainty
    return {
        "scenario": scenario.name,
        "scenario_file": str(scenario.source or ""),
        "data_files": [str(p) for p in data_files],
        "fitted": list(selection.quantities),
        "status": result.status,
        "converged": result.converged,
        "reason": result.reason,
        "method": result.method,
        "iterations": result.n_iterations,
        "simulations": result.n_simulations,
        "rejected_steps": result.n_rejected,
        "wall_time_s": result.wall_time,
        "loss_history": result.loss_history,
        "noise_scale": unc.noise_scale,
        "initial_state_rule": initial,
        "feedforward_rule": feedforward,
        "stderr_meaningful": result.stderr_meaningful,
        "misfit": None
        if result.misfit is None
        else {
            "ratio": result.misfit.ratio,
            "threshold": result.misfit.threshold,
            "declared_noise": result.misfit.declared,
            "noise_floor": result.misfit.noise_floor,
            "autocorrelation": result.misfit.autocorrelation,
            "worst": [
                {
                    "channel": result.misfit.channel_name(
                        w, scenario.names, scenario.model.convention
                    ),
                    "ratio": w.ratio,
                    "time": w.time,
                }
                for w in result.misfit.worst
            ],
        },
        "uncertainty_note": unc.reason,
        "notes": list(result.notes),
        "parameters": [
            {
                "name": row.name,
                "estimate": row.estimate,
                "stderr": row.stderr,
                "relative_stderr": row.relative_stderr,
                "initial": row.initial,
                "start": row.start,
                "identifiable": row.identifiable,
            }
            for row in result.table
        ],
        "correlation": {"names": list(result.names), "matrix": result.correlation},
    }


def write_results(
    scenario,
    experiments,
    result,
    selection,
    folder,
    args,
    initial="frozen",
    feedforward="frozen",
) -> list:
    """Write the fitted scenario (with the fit's initial-state rule `initial`),
    the report and the plots into `folder` as a whole; returns the paths."""
    when = datetime.datetime.now().isoformat(timespec="seconds")
    header = (
        f"{scenario.name}: fitted by elasticoop identify on {when}\n"
        f"from {', '.join(str(p) for p in args.data)} "
        f"(fitted: {', '.join(selection.quantities)}; status {result.status});\n"
        f"estimates and standard errors in report.txt beside this file."
    )
    files = {
        "fitted_scenario.toml": fitted_scenario_text(
            scenario,
            result.model,
            header,
            initial=initial,
            initial_state=result.initial_states[0] if result.initial_states else None,
            freeze_feedforward=feedforward == "frozen",
        ),
        "report.txt": result.report() + "\n",
        "report.json": strict_json(
            report_data(scenario, result, selection, args.data, initial, feedforward)
        ),
    }
    with folder.writing() as staging:
        for name, text in files.items():
            (staging / name).write_text(text, encoding="utf-8")
        names = list(files)
        if not args.no_plots:
            names += write_plots(scenario, experiments, result, staging, args)
    return [folder.path / name for name in names]


def write_plots(scenario, experiments, result, outdir: pathlib.Path, args) -> list:
    from .._plotting import plot_fit, plot_loss_history

    misfit = result.misfit
    floor = misfit.noise_floor if misfit is not None and misfit.declared else None
    plot_loss_history(result.loss_history, noise_floor=floor).savefig(
        outdir / "loss_history.png", dpi=110
    )
    names = ["loss_history.png"]
    kwargs = scenario.options.kwargs()
    starts = result.initial_states or [(e.y_init, e.ydot_init) for e in experiments]
    for k, (path, e, (y0, ydot0)) in enumerate(zip(args.data, experiments, starts), 1):
        traj = simulate(
            result.model,
            y0,
            ydot0,
            e.ts,
            forces=e.forces,
            throw=False,
            **kwargs,
        )
        fig = plot_fit(
            e.ts,
            e.y,
            np.asarray(traj.y),
            scenario.names,
            scenario.model.convention,
            title=f"{pathlib.Path(path).name}: measured (dots) and fitted (line)",
        )
        fig.savefig(outdir / f"fit_{k}.png", dpi=100)
        names.append(f"fit_{k}.png")
    return names


def renamed(text: str, old: Sequence[str], new: Sequence[str]) -> str:
    """`text` with each parameter name of `old` replaced by the one at the same
    place in `new` (the library's index names by the scenario's names)."""
    mapping = dict(zip(old, new))
    if not mapping:
        return text
    pattern = "|".join(re.escape(name) for name in sorted(mapping, key=len)[::-1])
    return re.sub(pattern, lambda match: mapping[match.group(0)], text)
