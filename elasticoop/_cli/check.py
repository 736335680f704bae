"""`elasticoop check FILE...`: validate scenario files, and Monte Carlo study files,
without simulating."""

import os
import sys
import tomllib

import numpy as np

from .._config import ScenarioError
from .._config.limits import (
    MAX_OUTPUT_BYTES,
    MAX_SCENARIO_FILE_BYTES,
    format_bytes,
    output_bytes,
    run_files_bytes,
)
from .._forces import SampledForce
from ._common import EXIT_OK, EXIT_USAGE, common_options, load, say

NAME = "check"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="validate scenario and study files (no simulation)",
        description=(
            "Validate one or more TOML scenario files: every table and key, the "
            "bodies named by connections, initial states, forces and prescribed "
            "coordinates, and the data files they refer to. All problems of a "
            "file are listed at once. Exit code 0 when all files are valid, 2 "
            "otherwise. A Monte Carlo study file (*.study.toml, or a file with a "
            "[sampling] table) is checked as 'elasticoop montecarlo' reads it, "
            "with its scenario."
        ),
    )
    parser.add_argument(
        "scenarios",
        metavar="FILE",
        nargs="+",
        help="TOML scenario or study file(s)",
    )
    parser.set_defaults(func=execute)


def scenario_lines(scenario) -> list[str]:
    """A few lines describing a loaded scenario."""
    model = scenario.model
    kind = type(model).__name__
    links = (
        f", {len(scenario.connection_names)} connections"
        if scenario.connection_names
        else ""
    )
    ts = np.asarray(scenario.ts)
    forces = type(scenario.forces).__name__ if scenario.forces is not None else "none"
    if isinstance(scenario.forces, SampledForce):
        samples = scenario.forces.ts
        forces += (
            f", {samples.size} samples from {float(samples[0]):g} to "
            f"{float(samples[-1]):g} s; {scenario.forces.jump_ts.size} of them "
            f"handed to the solver as jump times (the kinks)"
        )
    counts = (
        model.n_bodies,
        len(scenario.connection_names),
        scenario.prescribed is not None,
    )
    results = output_bytes(ts.size, *counts)
    files = sum(run_files_bytes(ts.size, *counts, plots=True).values())
    lines = [
        f"  model: {kind} ({model.convention}), {model.n_bodies} bodies "
        f"({', '.join(scenario.names)}){links}, gravity {float(model.gravity)} m/s^2",
        f"  time: {ts[0]:g} to {ts[-1]:g} s, {ts.size} output samples; solver "
        f"{scenario.solver} (rtol {scenario.rtol:g}, atol {scenario.atol:g}, "
        f"max_steps {scenario.max_steps})",
        f"  results: about {format_bytes(results)} "
        f"(limit {format_bytes(MAX_OUTPUT_BYTES)}); the files of a run take up "
        f"to {format_bytes(files)} on disk",
        f"  forces: {forces}",
    ]
    if scenario.prescribed is not None:
        spec = scenario.prescribed
        motion = "hold" if spec.hold else f"{spec.ts.size} CSV samples"
        lines.append(f"  prescribed: {int(spec.mask.sum())} coordinates ({motion})")
    return lines


def _is_study_file(path: str) -> bool:
    """Whether `path` names a Monte Carlo study file: `*.study.toml`, as the shipped
    one, or a TOML file with a `[sampling]` table (a scenario file has none)."""
    if str(path).endswith(".study.toml"):
        return True
    # (whatever cannot be read, or is too large to, is left to the scenario's
    # loader, which names the problem)
    try:
        if os.path.getsize(path) > MAX_SCENARIO_FILE_BYTES:
            return False
        with open(path, encoding="utf-8-sig") as file:
            return "sampling" in tomllib.loads(file.read())
    except (OSError, tomllib.TOMLDecodeError, UnicodeDecodeError, RecursionError):
        return False


def study_lines(study_file) -> list[str]:
    """A few lines describing a loaded study file."""
    study = study_file.study
    return [
        f"  scenario: {study_file.scenario_file}",
        f"  {study.n_samples} samples ({study.sampling}), parameters: "
        + ", ".join(p.name for p in study.parameters),
        f"  outputs: {', '.join(study.outputs)}",
    ]


def execute(args) -> int:
    errors = []
    for path in args.scenarios:
        try:
            if _is_study_file(path):
                from .._config import load_study

                study_file = load_study(path)
                say(
                    args,
                    f"{path}: valid study file '{study_file.name}'",
                    *study_lines(study_file),
                )
                continue
            scenario = load(path)
        except ScenarioError as err:
            errors.append(err)
            continue
        say(
            args, f"{path}: valid scenario '{scenario.name}'", *scenario_lines(scenario)
        )
    if len(errors) == 1 and len(args.scenarios) == 1:
        raise errors[0]
    for error in errors:
        print(f"elasticoop check: error: {error}", file=sys.stderr)
    return EXIT_USAGE if errors else EXIT_OK
