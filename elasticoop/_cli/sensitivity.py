"""`elasticoop montecarlo sensitivity STUDY.toml -o STORE`: run the design of the
study file's `[sensitivity]` table and print the indices with their intervals;
`elasticoop montecarlo sensitivity STORE`: analyse such a store again. Both write
into STORE/sensitivity/ the indices (JSON and netCDF), the convergence table and
the plots."""

import contextlib
import json
import os
import pathlib

import numpy as np
from pydantic import ValidationError

from .._config import load_study
from .._config.problems import message_of
from .._config.study_schema import SensitivityTable
from .._io.strict_json import strict_json
from ..montecarlo import (
    StoreError,
    StoreLockedError,
    StudyTooLargeError,
    open_study,
    run_study,
)
from ..montecarlo.distributed import is_first_process
from ..montecarlo.sampling import rows_per_point
from ._common import EXIT_OK, UserError, say, shows_progress, write_text_atomic

FOLDER = "sensitivity"
RECORD = "study_file.json"  # shared with `montecarlo` (its STUDY_FILE_RECORD)
TOP = 10  # factors printed per output element


def execute(args, read_record, use_cache) -> int:
    """The `sensitivity` word of `elasticoop montecarlo` (`read_record` reads the
    study file's record in a store, `use_cache` opens the compilation cache: the
    `montecarlo` command's own)."""
    if args.store is None:
        raise UserError(
            "give a study file and a store (elasticoop montecarlo sensitivity "
            "STUDY.toml -o STORE) or a store to analyse again (elasticoop "
            "montecarlo sensitivity STORE)"
        )
    target = pathlib.Path(args.store)
    if target.is_dir():
        if args.output or args.samples:
            raise UserError(
                f"{target} is a store: -o and --samples apply to running a study file"
            )
        return analyse(args, target, None, None, read_record(target))
    if not args.output:
        raise UserError("give the folder of the results with -o STORE")
    store = pathlib.Path(args.output)
    if store.exists() and not store.is_dir():
        raise UserError(f"the store {store} exists and is not a folder")
    study_file = load_study(target)
    table = study_file.sensitivity or SensitivityTable()
    if args.samples is not None:
        table = _with_samples(table, args.samples)
    from ..montecarlo import sensitivity_study

    study = sensitivity_study(
        study_file.study, table.method, table.samples, table.second_order
    )
    say(
        args,
        f"elasticoop montecarlo sensitivity: {study_file.name} ({target}): "
        f"{table.method}, {table.samples} base points, {study.n_samples} runs",
    )
    record = {
        "study_file": os.path.abspath(study_file.source),
        "scenario_file": study_file.scenario_file,
        "name": study_file.name,
        "thresholds": {k: list(v) for k, v in study_file.thresholds.items()},
        "units": study_file.units,
        "sensitivity": table.model_dump(),
    }
    with contextlib.ExitStack() as stack:
        use_cache(stack)
        try:
            run_study(
                study,
                store,
                batch_width=args.batch_width,
                progress=shows_progress(args),
                on_chunk=lambda _chunk: _keep(store, record),
            )
        except (StoreError, StoreLockedError, StudyTooLargeError) as err:
            raise UserError(str(err)) from err
    _keep(store, record)
    if not is_first_process():
        return EXIT_OK
    return analyse(args, store, table, study, record)


def _with_samples(table: SensitivityTable, samples: int) -> SensitivityTable:
    """`table` with the base points of `--samples`, or a `UserError` naming the
    option and why its value does not fit the table's method."""
    try:
        return SensitivityTable.model_validate(
            table.model_dump() | {"samples": samples}
        )
    except ValidationError as err:
        reasons = [message_of(dict(e)) for e in err.errors()]
        reasons = [r.removeprefix(f"samples = {samples}: ") for r in reasons]
        raise UserError(f"--samples {samples}: {'; '.join(reasons)}") from err


def _keep(store: pathlib.Path, record: dict) -> None:
    if is_first_process():
        write_text_atomic(store / RECORD, strict_json(record))


def analyse(args, store: pathlib.Path, table, study, record: dict) -> int:
    try:
        ds = open_study(store)
    except StoreError as err:
        raise UserError(str(err)) from err
    if table is None:
        try:
            table = SensitivityTable.model_validate(record.get("sensitivity", {}))
        except ValueError as err:
            raise UserError(f"{store / RECORD}: its sensitivity entry: {err}") from err
    design = json.loads(ds.attrs["study"])["sampling"]
    folder = store / FOLDER
    folder.mkdir(exist_ok=True)
    name = record.get("name", str(store))
    if design in ("saltelli", "saltelli-second-order"):
        paths = _sobol(args, ds, table, study, record, folder, name)
    elif design == "morris":
        paths = _morris(args, ds, table, folder, name)
    elif table.method == "dgsm":
        paths = _dgsm_only(args, ds, table, study, record, folder, name)
    else:
        raise UserError(
            f"the store {store} was drawn with sampling {design!r}: Sobol' indices "
            f"need the Saltelli design and Morris effects the Morris design; run "
            f"'elasticoop montecarlo sensitivity STUDY.toml -o NEW_STORE' with a "
            f"[sensitivity] table"
        )
    say(args, "wrote " + ", ".join(str(p) for p in paths))
    return EXIT_OK


def _study_of(study, record):
    """The study (for derivatives): the one run, or the recorded study file's."""
    if study is not None:
        return study
    file = record.get("study_file")
    if not file or not pathlib.Path(file).is_file():
        raise UserError(
            "derivatives need the study file: run 'elasticoop montecarlo "
            "sensitivity STUDY.toml -o STORE'"
        )
    from ..montecarlo import sensitivity_study

    table = SensitivityTable.model_validate(record["sensitivity"])
    return sensitivity_study(
        load_study(file).study, table.method, table.samples, table.second_order
    )


def _sobol(args, ds, table, study, record, folder, name) -> list:
    from .._plotting import (
        plot_sobol_convergence,
        plot_sobol_heatmap,
        plot_sobol_indices,
    )
    from ..montecarlo import (
        check_dgsm_bounds,
        convergence_table,
        dgsm,
        sobol_convergence,
        sobol_indices,
    )

    options = dict(bootstrap=table.bootstrap, confidence=table.confidence)
    indices = sobol_indices(ds, table.outputs, **options)
    scalar = [o for o in _outputs(ds, table) if "time" not in ds[o].dims]
    say(args, _format_indices(indices, name))
    paths = [folder / "indices.nc", folder / "indices.json"]
    indices.to_netcdf(paths[0], engine="h5netcdf")
    report: dict = {"indices": _as_json(indices)}
    for output in _outputs(ds, table):
        figure = plot_sobol_indices(indices, output)
        paths.append(folder / f"sobol_{output}.png")
        figure.savefig(paths[-1], dpi=110)
        if "time" in ds[output].dims:
            paths.append(folder / f"heatmap_{output}.png")
            plot_sobol_heatmap(indices, output).savefig(paths[-1], dpi=110)
    if scalar:
        convergence = sobol_convergence(ds, scalar, **options)
        rows = convergence_table(convergence)
        report["convergence"] = rows
        say(args, _format_convergence(rows, table.confidence))
        for output in scalar:
            paths.append(folder / f"convergence_{output}.png")
            plot_sobol_convergence(convergence, output).savefig(paths[-1], dpi=110)
    if table.dgsm_samples:
        study = _study_of(study, record)
        block = rows_per_point(study.sampling, indices.sizes["factor"])
        points = min(table.dgsm_samples, indices.attrs["base_samples"])
        measures = dgsm(
            study, np.arange(points) * block, table.outputs, **options
        )  # the rows A of the first base points
        check = check_dgsm_bounds(indices, measures)
        report["dgsm_bounds"] = _as_json(check)
        say(args, _format_bounds(check, points))
    paths[1].write_text(strict_json(report))
    return paths


def _outputs(ds, table) -> list[str]:
    return list(table.outputs or json.loads(ds.attrs["study"])["outputs"])


def _morris(args, ds, table, folder, name) -> list:
    from .._plotting import plot_morris
    from ..montecarlo import morris_effects

    effects = morris_effects(
        ds, table.outputs, bootstrap=table.bootstrap, confidence=table.confidence
    )
    say(args, _format_morris(effects, name))
    paths = [folder / "morris.nc", folder / "morris.json"]
    effects.to_netcdf(paths[0], engine="h5netcdf")
    paths[1].write_text(strict_json({"morris": _as_json(effects)}))
    for output in _outputs(ds, table):
        paths.append(folder / f"morris_{output}.png")
        plot_morris(effects, output).savefig(paths[-1], dpi=110)
    return paths


def _dgsm_only(args, ds, table, study, record, folder, name) -> list:
    from ..montecarlo import dgsm

    study = _study_of(study, record)
    points = min(table.dgsm_samples or table.samples, ds.sizes["sample"])
    measures = dgsm(
        study,
        np.arange(points),
        table.outputs,
        bootstrap=table.bootstrap,
        confidence=table.confidence,
    )
    lines = [
        f"{name}: derivative-based measures at {points} points and their bound "
        f"C nu / Var(Y) on each total index ({100 * table.confidence:g} % intervals)"
    ]
    for key in measures.data_vars:
        key = str(key)
        if not key.startswith("dgsm_bound_") or key.startswith(
            ("dgsm_bound_low_", "dgsm_bound_high_")
        ):
            continue
        output = key[len("dgsm_bound_") :]
        bound = measures[key]
        if "time" in bound.dims:
            lines.append(f"  {output}: a time series; see dgsm.nc")
            continue
        for label, sel in _elements(bound):
            lines.append(f"  {output}{label}:  factor  bound [low, high]")
            values = bound.isel(sel).values
            low = measures[f"dgsm_bound_low_{output}"].isel(sel).values
            high = measures[f"dgsm_bound_high_{output}"].isel(sel).values
            for k in np.argsort(-np.nan_to_num(values, nan=-1.0))[:TOP]:
                lines.append(
                    f"    {bound['factor'].values[k]:<28} {values[k]:8.3g} "
                    f"[{low[k]:.3g}, {high[k]:.3g}]"
                )
    say(args, "\n".join(lines))
    paths = [folder / "dgsm.nc", folder / "dgsm.json"]
    measures.to_netcdf(paths[0], engine="h5netcdf")
    paths[1].write_text(strict_json({"dgsm": _as_json(measures)}))
    return paths


# -- text --------------------------------------------------------------------------


def _elements(da):
    """(label, selection) of each element of `da` over its dims other than
    `factor` (and `factor_2`)."""
    dims = [d for d in da.dims if d not in ("factor", "factor_2")]
    for index in np.ndindex(*[da.sizes[d] for d in dims]):
        selection = dict(zip(dims, index))
        labels = [
            str(da[d].values[k]) if d in da.coords else str(k)
            for d, k in selection.items()
        ]
        yield ("[" + ", ".join(labels) + "]" if labels else ""), selection


def _format_indices(indices, name) -> str:
    level = 100 * indices.attrs["confidence"]
    lines = [
        f"{name}: Sobol' indices from {indices.attrs['base_samples']} base points "
        f"({indices.attrs['runs']} runs), {level:g} % bootstrap intervals "
        f"({indices.attrs['bootstrap']} resamples)"
    ]
    for key in indices.data_vars:
        key = str(key)
        if not key.startswith("ST_") or key.startswith("ST_conf_"):
            continue
        output = key[3:]
        st = indices[key]
        if "time" in st.dims:
            lines.append(
                f"  {output}: a time series; its indices at every time are in "
                f"indices.nc and heatmap_{output}.png"
            )
            continue
        for label, sel in _elements(st):
            lines.append(f"  {output}{label}:  factor  S1 +- conf  ST +- conf")
            total = st.isel(sel).values
            if not np.isfinite(total).any():
                lines.append("    (does not vary)")
                continue
            order = np.argsort(-np.nan_to_num(total, nan=-1.0), kind="stable")
            for k in order[:TOP]:
                s1 = indices[f"S1_{output}"].isel(sel).values[k]
                c1 = indices[f"S1_conf_{output}"].isel(sel).values[k]
                ct = indices[f"ST_conf_{output}"].isel(sel).values[k]
                lines.append(
                    f"    {st['factor'].values[k]:<28} {s1:7.3f} +- {c1:.3f}"
                    f"  {total[k]:7.3f} +- {ct:.3f}"
                )
            rest = len(order) - TOP
            if rest > 0:
                lines.append(f"    ({rest} more factors with smaller ST)")
    return "\n".join(lines)


def _format_convergence(rows, confidence) -> str:
    lines = [
        f"convergence: the largest {100 * confidence:g} % interval half-width of "
        f"the indices against the base points"
    ]
    lines.append(
        "  output                     base    runs  max S1 conf  max ST conf  top ST"
    )
    for r in rows:
        lines.append(
            f"  {r['output']:<26} {r['base_samples']:>4} {r['runs']:>7}"
            f"  {r['max_S1_conf']:11.3f}  {r['max_ST_conf']:11.3f}"
            f"  {r['top_ST']:.3f} ({r['top_factor']})"
        )
    return "\n".join(lines)


def _format_bounds(check, points) -> str:
    lines = [
        f"DGSM bound ST <= C nu / Var(Y) from exact derivatives at {points} points:"
    ]
    for key in check.data_vars:
        key = str(key)
        if not key.startswith("bound_holds_"):
            continue
        output = key[len("bound_holds_") :]
        holds = check[key].values
        checked = np.isfinite(holds)
        failed = int((holds[checked] == 0).sum())
        lines.append(
            f"  {output}: {int(checked.sum())} (factor, element) pairs checked, "
            f"{failed} violated"
        )
    return "\n".join(lines)


def _format_morris(effects, name) -> str:
    lines = [
        f"{name}: Morris elementary effects, {effects.attrs['trajectories']} "
        f"trajectories ({effects.attrs['runs']} runs)"
    ]
    for key in effects.data_vars:
        key = str(key)
        if not key.startswith("mu_star_") or key.startswith("mu_star_conf_"):
            continue
        output = key[len("mu_star_") :]
        mu = effects[key]
        if "time" in mu.dims:
            mu = mu.isel(time=-1)
        for label, sel in _elements(mu):
            lines.append(f"  {output}{label}:  factor  mu* +- conf  sigma")
            values = mu.isel(sel).values
            for k in np.argsort(-np.nan_to_num(values, nan=-1.0))[:TOP]:
                conf = effects[f"mu_star_conf_{output}"]
                sigma = effects[f"sigma_{output}"]
                if "time" in conf.dims:
                    conf, sigma = conf.isel(time=-1), sigma.isel(time=-1)
                lines.append(
                    f"    {mu['factor'].values[k]:<28} {values[k]:10.4g} +- "
                    f"{conf.isel(sel).values[k]:.3g}  {sigma.isel(sel).values[k]:.4g}"
                )
    return "\n".join(lines)


def _as_json(ds) -> dict:
    """The variables without a time axis as nested lists, with their dims and
    coordinates."""
    out: dict = {"attrs": dict(ds.attrs), "coords": {}, "variables": {}}
    for key, da in ds.data_vars.items():
        if "time" in da.dims:
            continue
        out["variables"][str(key)] = {"dims": list(da.dims), "data": da.values}
    for key, coord in ds.coords.items():
        if key != "time":
            out["coords"][str(key)] = [str(v) for v in coord.values]
    return out
