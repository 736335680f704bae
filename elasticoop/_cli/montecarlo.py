"""`elasticoop montecarlo STUDY.toml -o STORE`: run (or resume) the Monte Carlo
study a study file describes; `elasticoop montecarlo summary STORE`: print its
statistics and exceedance probabilities and draw its plots."""

import argparse
import contextlib
import json
import os
import pathlib

from .._cache import compilation_cache
from .._config import load_study
from .._io.strict_json import strict_json
from .._io.study_summary import format_study_report, output_names, study_report
from ..montecarlo import (
    StoreError,
    StoreLockedError,
    StudyTooLargeError,
    open_study,
    run_study,
)
from ..montecarlo.distributed import is_first_process
from ..montecarlo.execution import ACCELERATOR_BATCH_WIDTH, DEFAULT_BATCH_WIDTH
from ..montecarlo.store import check_store_folder
from . import sensitivity
from ._common import (
    EXIT_OK,
    UserError,
    common_options,
    positive_int,
    say,
    shows_progress,
    write_text_atomic,
)

NAME = "montecarlo"
SUMMARY = "summary"
# What the command line keeps in the store beside the results: the study file's
# thresholds and units, for `summary`.
STUDY_FILE_RECORD = "study_file.json"
SUMMARY_FOLDER = "summary"


def register(subparsers) -> None:
    parser = subparsers.add_parser(
        NAME,
        parents=[common_options()],
        help="run a Monte Carlo study file, or summarise its results",
        usage=(
            "elasticoop montecarlo STUDY.toml -o STORE [options]\n"
            "       elasticoop montecarlo summary STORE [-q]\n"
            "       elasticoop montecarlo sensitivity STUDY.toml -o STORE | STORE"
        ),
        description=(
            "Run the Monte Carlo study that the study file STUDY.toml describes "
            "(see 'elasticoop examples' for one) and keep every sample's result in "
            "the folder STORE, chunk by chunk, with a progress bar on a terminal. "
            "Running the same command again resumes an interrupted study; a STORE "
            "of a different study is refused. At the end the sample counts, statistics "
            "and exceedance probabilities are printed. 'elasticoop montecarlo "
            "summary STORE' prints them again, writes them to STORE/summary/"
            "summary.json and draws into STORE/summary/ the quantile bands of the "
            "outputs over time, the histograms of the other outputs and their "
            "sensitivity ranking (Spearman rank correlations). 'elasticoop "
            "montecarlo sensitivity STUDY.toml -o STORE' runs the design of the "
            "study file's [sensitivity] table (Sobol', Morris or DGSM; --samples "
            "sets its base points) and writes the indices, with their intervals, "
            "and their plots into STORE/sensitivity/; 'elasticoop montecarlo "
            "sensitivity STORE' analyses such a store again. Exit code 0 on "
            "success, 2 for an invalid study or scenario file or an unusable "
            "STORE. Failed samples never stop the study: they are counted."
        ),
    )
    parser.add_argument(
        "target",
        metavar="STUDY.toml",
        help="the study file (or the word 'summary' or 'sensitivity', see above)",
    )
    parser.add_argument("store", metavar="STORE", nargs="?", help=argparse.SUPPRESS)
    parser.add_argument(
        "-o", "--output", metavar="STORE", help="folder of the study's results"
    )
    parser.add_argument(
        "--samples",
        type=positive_int,
        metavar="N",
        help="draw N samples instead of the study file's (a trial run; more "
        "samples extend a store, except a Latin hypercube's); with 'sensitivity', "
        "N base points of its design instead of the [sensitivity] table's",
    )
    parser.add_argument(
        "--batch-width",
        type=positive_int,
        metavar="N",
        help=f"samples integrated together per device (default {DEFAULT_BATCH_WIDTH}"
        f" on CPUs, {ACCELERATOR_BATCH_WIDTH} on GPUs, or fewer when the samples do "
        "not fill every device, halved until a batch fits the memory budget; a "
        "resumed store keeps its own)",
    )
    distributed = parser.add_argument_group(
        "several processes (jax.distributed; every process runs the same command, "
        "STORE on a shared file system)"
    )
    distributed.add_argument(
        "--processes", type=positive_int, metavar="N", help="number of processes"
    )
    distributed.add_argument(
        "--process-id", type=int, metavar="K", help="this process's number, 0..N-1"
    )
    distributed.add_argument(
        "--coordinator",
        metavar="HOST:PORT",
        help="address of process 0 (it hosts the coordinator)",
    )
    parser.set_defaults(func=execute)


def execute(args) -> int:
    if args.target == "sensitivity":
        return sensitivity.execute(args, read_record, _use_cache)
    if args.target == SUMMARY:
        return summarise(args)
    return run(args)


# -- running a study ------------------------------------------------------------------


def run(args) -> int:
    if args.store is not None:
        raise UserError(
            f"unexpected argument {args.store!r}: give the store with -o STORE "
            f"(or run 'elasticoop montecarlo summary STORE')"
        )
    if not args.output:
        raise UserError("give the folder of the results with -o STORE")
    start_processes(args)
    store = pathlib.Path(args.output)
    try:
        # a file, or a folder of other files: refused before the study is built
        check_store_folder(store)
    except StoreError as err:
        raise UserError(str(err)) from err
    study_file = load_study(args.target, samples=args.samples)
    study = study_file.study
    say(args, f"elasticoop montecarlo: {study_file.name} ({args.target})")
    record = {
        "study_file": os.path.abspath(study_file.source),
        "scenario_file": study_file.scenario_file,
        "name": study_file.name,
        "thresholds": {k: list(v) for k, v in study_file.thresholds.items()},
        "units": study_file.units,
    }
    written: list[bool] = []

    def keep_record(_chunk=None) -> None:
        if not written and is_first_process():
            write_text_atomic(store / STUDY_FILE_RECORD, strict_json(record))
            written.append(True)

    with contextlib.ExitStack() as stack:
        _use_cache(stack)
        try:
            ds = run_study(
                study,
                store,
                batch_width=args.batch_width,
                progress=shows_progress(args),
                on_chunk=keep_record,
            )
        except (StoreError, StoreLockedError, StudyTooLargeError) as err:
            raise UserError(str(err)) from err
    keep_record()
    if is_first_process():
        report = study_report(ds, study_file.thresholds, study_file.units)
        say(args, format_study_report(report, study_file.name))
        say(args, f"results in {store}; plots: elasticoop montecarlo summary {store}")
    return EXIT_OK


def start_processes(args) -> None:
    """`jax.distributed.initialize` with `--processes`, `--process-id` and
    `--coordinator` (all three, or none)."""
    given = [args.processes, args.process_id, args.coordinator]
    if all(v is None for v in given):
        return
    if any(v is None for v in given):
        raise UserError(
            "--processes, --process-id and --coordinator go together: give all three"
        )
    if not 0 <= args.process_id < args.processes:
        raise UserError(
            f"--process-id must be in 0..{args.processes - 1}, got {args.process_id}"
        )
    import jax

    jax.distributed.initialize(
        coordinator_address=args.coordinator,
        num_processes=args.processes,
        process_id=args.process_id,
    )


def _use_cache(stack: contextlib.ExitStack) -> None:
    try:
        stack.enter_context(compilation_cache())
    except (ValueError, OSError) as err:
        raise UserError(
            f"cannot use the compilation cache folder ({err}); set "
            "ELASTICOOP_CACHE_DIR to a writable folder"
        ) from err


# -- summarising its results ----------------------------------------------------------


def summarise(args) -> int:
    misplaced = [
        option
        for option, value in (
            ("-o", args.output),
            ("--samples", args.samples),
            ("--batch-width", args.batch_width),
            ("--processes", args.processes),
            ("--process-id", args.process_id),
            ("--coordinator", args.coordinator),
        )
        if value is not None
    ]
    if misplaced:
        raise UserError(
            f"{', '.join(misplaced)} appl{'y' if len(misplaced) > 1 else 'ies'} to "
            f"running a study, not to 'summary STORE'"
        )
    if args.store is None:
        raise UserError("give the study's store: elasticoop montecarlo summary STORE")
    store = pathlib.Path(args.store)
    if not store.is_dir():
        raise UserError(f"no study store {store} (not a folder)")
    try:
        ds = open_study(store)
    except StoreError as err:
        raise UserError(str(err)) from err
    record = read_record(store)
    thresholds = record.get("thresholds", {})
    units = record.get("units", {})
    report = study_report(ds, thresholds, units)
    say(args, format_study_report(report, record.get("name", str(store))))
    folder = store / SUMMARY_FOLDER
    paths = write_summary(ds, report, thresholds, units, folder)
    say(args, "wrote " + ", ".join(str(p) for p in paths))
    return EXIT_OK


def read_record(store: pathlib.Path) -> dict:
    """What the command line recorded of the study file in the store (empty for
    a store written by `run_study` directly)."""
    file = store / STUDY_FILE_RECORD
    if not file.is_file():
        return {}
    try:
        record = json.loads(file.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UserError(f"{file} cannot be read: {err}") from err
    if not isinstance(record, dict):
        raise UserError(f"{file} is damaged: it holds no table")
    return record


def write_summary(ds, report, thresholds, units, folder: pathlib.Path) -> list:
    """`summary.json` and the plots of every output into `folder`."""
    from .._plotting import (
        plot_study_histograms,
        plot_study_quantiles,
        plot_study_sensitivity,
    )

    try:
        folder.mkdir(exist_ok=True)
    except OSError as err:
        raise UserError(f"cannot make the folder {folder}: {err.strerror}") from err
    paths = [folder / "summary.json"]
    write_text_atomic(paths[0], strict_json(report))
    for name in output_names(ds):
        entry = report["outputs"][name]
        unit = units.get(name)
        if "elements" not in entry:
            if not entry["n_valid"]:
                continue
            figures = {f"quantiles_{name}.png": plot_study_quantiles(ds, name, unit)}
        elif not entry["elements"]:
            continue
        else:
            figures = {
                f"histogram_{name}.png": plot_study_histograms(
                    ds, name, thresholds.get(name, ()), unit
                )
            }
            if any("rank_correlation" in e for e in entry["elements"].values()):
                figures[f"sensitivity_{name}.png"] = plot_study_sensitivity(ds, name)
        for file, figure in figures.items():
            try:
                figure.savefig(folder / file, dpi=110)
            except OSError as err:
                raise UserError(
                    f"cannot write {folder / file}: {err.strerror or err}"
                ) from err
            paths.append(folder / file)
    return paths
