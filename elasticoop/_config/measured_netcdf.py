"""The netCDF format of measured motion: the layout of the `trajectory.nc` that
`elasticoop run` writes (`docs/data_files.md`), so a simulated run can be fed back
as data.

Variable `y` (and optionally `ydot`) with dimensions `(time, body, coordinate)`,
labelled by the scenario's body and coordinate names; the coordinate `time` [s];
the optional coordinate `coordinate_unit` (`m`, `rad` or `deg` per coordinate);
optional noise levels `sigma_y` and `sigma_ydot` with dimensions
`(body, coordinate)`. Other variables are ignored. NaN marks a missing sample.
"""

import math
import pathlib

import numpy as np

from .._naming import TRANSLATION_NAMES, coordinate_names
from .limits import MAX_MAGNITUDE, magnitude_problem
from .measured_samples import MeasuredData, check_samples_size
from .problems import DataFileError, DataProblem

DIMS = ("time", "body", "coordinate")
_ANGLE_FACTORS = {
    "rad": 1.0,
    "radians": 1.0,
    "deg": math.pi / 180,
    "degrees": math.pi / 180,
}


def read_measured_netcdf(path: pathlib.Path, source: str, scenario) -> MeasuredData:
    """The samples of a measured-data netCDF file, checked against `scenario`;
    raises `DataFileError` listing every problem."""
    import xarray as xr

    problems: list[DataProblem] = []

    def add(column: str, row: str, message: str) -> None:
        problems.append(DataProblem(column, row, message))

    try:
        # times as written: a date ("seconds since ...") or a duration unit is
        # checked below, not converted by xarray into datetimes or timedeltas
        ds = xr.open_dataset(
            path, engine="h5netcdf", decode_times=False, decode_timedelta=False
        )
    except Exception as err:  # h5py/xarray raise many kinds for a damaged file
        raise DataFileError(
            source,
            [DataProblem("", "", f"not a readable netCDF file ({err})")],
        ) from None
    with ds:
        names = list(scenario.names)
        coords = list(coordinate_names(scenario.model.convention))
        convention = ds.attrs.get("convention")
        if convention is not None and convention != scenario.model.convention:
            add(
                "",
                "",
                f"the file's Euler angles follow convention '{convention}', the "
                f"scenario's '{scenario.model.convention}'",
            )
        if "y" not in ds.data_vars:
            add("y", "", "missing variable: the measured coordinates Y")
            raise DataFileError(source, problems)
        wanted = ["y"] + [v for v in ("ydot",) if v in ds.data_vars]
        for name in wanted:
            if tuple(ds[name].dims) != DIMS:
                add(
                    name,
                    "",
                    f"dimensions must be {DIMS}, got {tuple(ds[name].dims)}",
                )
        if problems:
            raise DataFileError(source, problems)
        bodies = [str(b) for b in ds["body"].values]
        file_coords = [str(c) for c in ds["coordinate"].values]
        for b in bodies:
            if b not in names:
                add("body", "", f"no body named '{b}' in the scenario ({names})")
        for b in names:
            if b not in bodies:
                add("body", "", f"the scenario's body '{b}' has no samples")
        if sorted(file_coords) != sorted(coords):
            add(
                "coordinate",
                "",
                f"coordinates {file_coords} do not match the scenario's convention "
                f"'{scenario.model.convention}' ({coords})",
            )
        factors = _angle_factors(ds, file_coords, add)
        ts = _time_values(ds, add)
        if ts is None:
            raise DataFileError(source, problems)
        too_large = check_samples_size(len(ts), len(names))
        if too_large:
            add("time", "", too_large)
        if problems:
            raise DataFileError(source, problems)
        _check_times(ts, add)
        order = dict(body=names, coordinate=coords)
        arrays = {}
        for name in wanted:
            values = np.asarray(ds[name].sel(order).values, dtype=np.float64)
            scale = np.array([factors[c] for c in coords])
            arrays[name] = values * scale
            _check_values(name, values, ts, add)
        sigma = _sigma(ds, "sigma_y", order, coords, factors, add)
        sigma_dot = _sigma(ds, "sigma_ydot", order, coords, factors, add)
    if problems:
        raise DataFileError(source, problems)
    return MeasuredData(ts, arrays["y"], arrays.get("ydot"), sigma, sigma_dot)


# Length units of the translations (to metres).
_LENGTH_FACTORS = {"m": 1.0, "cm": 1e-2, "mm": 1e-3}


def _angle_factors(ds, file_coords, add) -> dict[str, float]:
    """Factor to SI per coordinate, from the `coordinate_unit` coordinate (SI when
    it is missing)."""
    factors = {c: 1.0 for c in file_coords}
    if "coordinate_unit" not in ds.coords:
        return factors
    for c, unit in zip(file_coords, ds["coordinate_unit"].values):
        unit = str(unit)
        translation = c in TRANSLATION_NAMES
        accepted = tuple(_LENGTH_FACTORS) if translation else tuple(_ANGLE_FACTORS)
        if unit not in accepted:
            add(
                "coordinate_unit",
                "",
                f"unit '{unit}' of coordinate '{c}' not accepted: use "
                f"{' or '.join(repr(a) for a in accepted)}",
            )
            continue
        factors[c] = _LENGTH_FACTORS[unit] if translation else _ANGLE_FACTORS[unit]
    return factors


def _sample(ts, k) -> str:
    return f"sample {k} (t = {ts[k]:g} s)"


def _check_times(ts, add) -> None:
    if ts.ndim != 1 or len(ts) < 2:
        add("time", "", f"needs at least 2 samples, got {ts.size}")
        return
    for k in np.flatnonzero(~np.isfinite(ts))[:5]:
        add("time", f"sample {k}", f"the time is {ts[k]}")
    steps = np.diff(ts)
    for k in np.flatnonzero(~(steps > 0) & np.isfinite(steps))[:5]:
        add("time", _sample(ts, k + 1), f"times must increase (after t = {ts[k]:g} s)")


# The units accepted for the time coordinate (or none: seconds).
TIME_UNITS = ("s", "second", "seconds", "sec")


def _time_values(ds, add) -> np.ndarray | None:
    """The `time` coordinate in seconds, or `None` (with the problem added) when
    it is missing, not numbers, or in another unit (a date such as `seconds since
    2000-01-01`, milliseconds, ...)."""
    if "time" not in ds.variables:
        add("time", "", "missing coordinate: the sample times [s]")
        return None
    var = ds["time"]
    if var.dtype.kind not in "iuf":
        add(
            "time", "", f"the times must be numbers [s], got values of type {var.dtype}"
        )
        return None
    unit = var.attrs.get("units")
    if unit is not None and str(unit).strip() not in TIME_UNITS:
        hint = (
            " (a date: give the time in seconds from the start of the motion, "
            "units 's')"
            if " since " in str(unit)
            else " (give the times in seconds, units 's')"
        )
        add("time", "", f"units {str(unit)!r} are not seconds{hint}")
        return None
    ts = np.asarray(var.values, dtype=np.float64)
    for k in np.flatnonzero(np.isfinite(ts) & (np.abs(ts) > MAX_MAGNITUDE))[:5]:
        add("time", f"sample {k}", str(magnitude_problem(float(ts[k]))))
    return ts


def _check_values(name, values, ts, add) -> None:
    infinite = np.argwhere(np.isinf(values))
    for k, b, c in infinite[:5]:
        add(name, _sample(ts, k), f"infinite value at body {b}, coordinate {c}")
    huge = np.argwhere(np.isfinite(values) & (np.abs(values) > MAX_MAGNITUDE))
    for k, b, c in huge[:5]:
        problem = magnitude_problem(float(values[k, b, c]))
        add(name, _sample(ts, k), f"body {b}, coordinate {c}: {problem}")


def _sigma(ds, name, order, coords, factors, add) -> np.ndarray | None:
    if name not in ds.data_vars:
        return None
    var = ds[name]
    if tuple(var.dims) != ("body", "coordinate"):
        add(name, "", f"dimensions must be ('body', 'coordinate'), got {var.dims}")
        return None
    values = np.asarray(var.sel(order).values, dtype=np.float64)
    values = values * np.array([factors[c] for c in coords])
    if not np.all(np.isfinite(values) & (values > 0)):
        add(name, "", "noise levels must be positive finite numbers")
        return None
    outside = (values < 1 / MAX_MAGNITUDE) | (values > MAX_MAGNITUDE)
    if np.any(outside):
        b, c = (int(i) for i in np.argwhere(outside)[0])
        add(
            name,
            "",
            f"noise levels must lie within {1 / MAX_MAGNITUDE:g} and "
            f"{MAX_MAGNITUDE:g} (SI units), got {values[b, c]!r} at body {b}, "
            f"coordinate {c}",
        )
        return None
    return values
