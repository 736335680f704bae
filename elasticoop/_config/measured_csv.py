"""The CSV format of measured motion: one row per sample, one column per
measured quantity, named in the scenario's vocabulary (`docs/data_files.md`).

Header cells: `t` (or `time`) [s]; `<body>.<coordinate>` (also written
`y.<body>.<coordinate>`) for $Y$; `ydot.<body>.<coordinate>` for $\\dot Y$;
`<body>.<fx|fy|fz|q1|q2|q3>` for applied forces. A unit in brackets may follow a
name (`plate.roll [deg]`) and must for angles and angle rates. A row whose first
cell is `sigma` gives the noise levels (standard deviations, in the columns' units).
Lines starting with `#` are comments; an empty cell is a missing sample.
"""

import csv
import math
import pathlib
import re

import numpy as np

from .._naming import RESULT_SERIES, coordinate_names
from .data_files import TIME_COLUMNS
from .limits import MAX_MAGNITUDE, format_bytes, magnitude_problem
from .measured_samples import MeasuredData, check_samples_size
from .problems import DataFileError, DataProblem

FORCE_COMPONENTS = ("fx", "fy", "fz", "q1", "q2", "q3")
NOISE_ROW = "sigma"
# Accepted units per kind of column: unit -> factor to SI (angles to radians).
_DEGREE = math.pi / 180
UNITS = {
    "time": {"s": 1.0},
    "length": {"m": 1.0, "cm": 1e-2, "mm": 1e-3},
    "angle": {"rad": 1.0, "radians": 1.0, "deg": _DEGREE, "degrees": _DEGREE},
    "speed": {"m/s": 1.0, "cm/s": 1e-2, "mm/s": 1e-3},
    "angle_rate": {
        "rad/s": 1.0,
        "radians/s": 1.0,
        "deg/s": _DEGREE,
        "degrees/s": _DEGREE,
    },
    "force": {"N": 1.0},
    "torque": {"N m": 1.0, "Nm": 1.0, "N*m": 1.0},
}
_HEADER = re.compile(r"^(?P<name>[^\[\]]*?)\s*(?:\[(?P<unit>[^\[\]]*)\])?$")
MAX_CELL_PROBLEMS = 5  # per column; the rest are counted
MAX_HEADER_CHARACTERS = 200  # of a header cell (a body name, a coordinate, a unit)


class _Column:
    """What one header cell names: `kind` is "time", "y", "ydot" or "force";
    `body` and `index` (0..5) locate it; `factor` converts its unit to SI."""

    def __init__(self, label, kind, body=0, index=0, factor=1.0):
        self.label, self.kind = label, kind
        self.body, self.index, self.factor = body, index, factor


def read_measured_csv(path: pathlib.Path, source: str, scenario) -> MeasuredData:
    """The samples of a measured-data CSV file, checked against `scenario`;
    raises `DataFileError` listing every problem."""
    problems: list[DataProblem] = []

    def add(column: str, row: str, message: str) -> None:
        problems.append(DataProblem(column, row, message))

    try:
        # "utf-8-sig": a byte-order mark (as some spreadsheets write) is dropped
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise DataFileError(
            source, [DataProblem("", "", "not a text file (not UTF-8)")]
        ) from None
    too_many = check_cell_count(text)
    if too_many:
        raise DataFileError(source, [DataProblem("", "", too_many)])
    rows = _rows(text, add)
    if problems:  # lines that are not CSV
        raise DataFileError(source, problems)
    if not rows:
        raise DataFileError(source, [DataProblem("", "", "no header row")])
    header_line, header = rows[0]
    columns = _parse_header(header, header_line, scenario, add)
    noise, samples = None, []
    for number, cells in rows[1:]:
        first = cells[0].strip().lower() if cells else ""
        if first == NOISE_ROW:
            if noise is not None:
                add("", f"line {number}", f"a second '{NOISE_ROW}' row (one only)")
            noise = (number, cells)
        else:
            samples.append((number, cells))
        if len(cells) != len(header):
            add(
                "",
                f"line {number}",
                f"has {len(cells)} cells but the header (line {header_line}) has "
                f"{len(header)}",
            )
    if len(samples) < 2:
        add("", "", f"needs at least 2 rows of samples, got {len(samples)}")
    n_bodies = len(scenario.names)
    too_large = check_samples_size(len(samples), n_bodies)
    if too_large:
        add("", "", too_large)
    if too_large or len(samples) < 2:
        raise DataFileError(source, problems)
    header_ok = all(c is not None for c in columns)
    # cells of the columns that could be read are checked even when others could not
    values = _numbers(columns, samples, add)
    times = _times(columns, samples, values, scenario, add)
    if not header_ok:
        raise DataFileError(source, problems)
    sigma = _noise(columns, noise, add) if noise is not None else None
    _check_complete(columns, values, scenario, add)
    if problems:
        raise DataFileError(source, problems)
    return _assemble(columns, values, times, sigma, n_bodies)


# The cells of a CSV file read at most: each is held as text while the file is
# checked (about 70 bytes of memory each), so this keeps reading a file near
# 2 GiB of memory; about 2.8 million samples of 12 coordinates.
MAX_CSV_CELLS = 2**25
CELL_MEMORY_BYTES = 70


def check_cell_count(text: str) -> str | None:
    """A message, before the file is split into cells, when it holds more than
    `MAX_CSV_CELLS` (counted as its commas plus its lines: an upper bound)."""
    cells = text.count(",") + text.count("\n") + 1
    if cells <= MAX_CSV_CELLS:
        return None
    return (
        f"the file holds about {cells} cells, over the limit of {MAX_CSV_CELLS} "
        f"(reading them takes about {format_bytes(cells * CELL_MEMORY_BYTES)} of "
        "memory); resample the file or split it into several experiments"
    )


def _rows(text: str, add) -> list[tuple[int, list[str]]]:
    """`(line number, cells)` of the lines that are neither blank nor comments; a
    line the CSV reader refuses (a cell beyond its field size limit, a stray
    quote) is a problem."""
    rows: list[tuple[int, list[str]]] = []
    for number, line in enumerate(text.splitlines(), start=1):
        if not line.strip() or line.lstrip().startswith("#"):
            continue
        try:
            rows.extend(
                (number, cells) for cells in csv.reader([line], skipinitialspace=True)
            )
        except csv.Error as err:
            add("", f"line {number}", f"not a line of CSV ({err}): {shown(line)}")
    return rows


SHOWN_CHARACTERS = 40  # of a cell quoted in a message


def shown(text: str) -> str:
    """`text` quoted for a message: its start and its length when it is long."""
    if len(text) <= SHOWN_CHARACTERS:
        return repr(text)
    return f"{text[:SHOWN_CHARACTERS]!r}... ({len(text)} characters)"


def _parse_header(header, line, scenario, add) -> list[_Column | None]:
    """One `_Column` per header cell (`None` where the cell has a problem)."""
    names = list(scenario.names)
    coords = coordinate_names(scenario.model.convention)
    where = f"line {line} (header)"
    parsed: list[_Column | None] = []
    seen: dict[str, int] = {}
    results: list[str] = []  # columns of a run's results, named once together
    for position, cell in enumerate(header):
        text = cell.strip()
        match = _HEADER.match(text)
        if not text or match is None:
            add("", where, f"cell {position + 1} is not a column name: {shown(cell)}")
            parsed.append(None)
            continue
        label, unit = match["name"].strip(), match["unit"]
        unit = None if unit is None else unit.strip()
        invisible = sorted({f"U+{ord(ch):04X}" for ch in text if not ch.isprintable()})
        if invisible:
            add(
                "",
                where,
                f"cell {position + 1}, {shown(cell)}, holds invisible characters "
                f"({', '.join(invisible)}; U+FEFF is a byte-order mark): remove them",
            )
            parsed.append(None)
            continue
        if len(text) > MAX_HEADER_CHARACTERS:
            add("", where, f"cell {position + 1} is not a column name: {shown(cell)}")
            parsed.append(None)
            continue
        if label in seen:
            add(label, where, f"repeated column (also cell {seen[label] + 1})")
            parsed.append(None)
            continue
        seen[label] = position
        if label.split(".")[0] in RESULT_SERIES:
            results.append(label)
            parsed.append(None)
            continue
        parsed.append(_column(label, unit, names, coords, add, where))
    if results:
        listed = ", ".join(results[:3]) + (", ..." if len(results) > 3 else "")
        add(
            results[0],
            where,
            f"{len(results)} columns of a run's results ({listed}) are not measured "
            f"data: keep the time and the '<body>.<coordinate>' or "
            f"'y.<body>.<coordinate>' columns (and 'ydot.' ones if the rates were "
            f"measured), or give the run's trajectory.nc, which is read as data",
        )
    for k, column in enumerate(parsed):
        if k > 0 and column is not None and column.kind == "time":
            add(column.label, where, "the time column must come first")
            parsed[k] = None
    return parsed


def _column(label, unit, names, coords, add, where) -> _Column | None:
    if label in TIME_COLUMNS:
        factor = _unit_factor(label, unit, "time", add, where, required=False)
        return None if factor is None else _Column(label, "time", factor=factor)
    parts = label.split(".")
    kind = "y"
    if len(parts) == 3 and parts[0] in ("y", "ydot"):
        kind, parts = parts[0], parts[1:]
    if len(parts) != 2:
        add(
            label,
            where,
            "not a column name of measured data: expected 't', '<body>.<coordinate>', "
            "'ydot.<body>.<coordinate>' or '<body>.<force component>'",
        )
        return None
    body, part = parts
    if body not in names:
        add(label, where, f"no body named '{body}' (bodies: {', '.join(names)})")
        return None
    if part in coords:
        k = coords.index(part)
        if kind == "y":
            what = "length" if k < 3 else "angle"
        else:
            what = "speed" if k < 3 else "angle_rate"
        factor = _unit_factor(label, unit, what, add, where, required=k >= 3)
        if factor is None:
            return None
        return _Column(label, kind, names.index(body), k, factor)
    if part in FORCE_COMPONENTS and kind == "y" and len(label.split(".")) == 2:
        k = FORCE_COMPONENTS.index(part)
        what = "force" if k < 3 else "torque"
        factor = _unit_factor(label, unit, what, add, where, required=False)
        if factor is None:
            return None
        return _Column(label, "force", names.index(body), k, factor)
    add(
        label,
        where,
        f"'{part}' is not a coordinate ({', '.join(coords)}) or force component "
        f"({', '.join(FORCE_COMPONENTS)}) of body '{body}'",
    )
    return None


def _unit_factor(label, unit, what, add, where, required) -> float | None:
    units = UNITS[what]
    accepted = " or ".join(f"'{u}'" for u in units)
    if unit is None:
        if required:
            add(
                label,
                where,
                f"an angle column needs its unit: write '{label} [deg]' or "
                f"'{label} [rad]'"
                + ("" if what == "angle" else f" (per second: {accepted})"),
            )
            return None
        return 1.0
    if unit not in units:
        add(label, where, f"unit '{unit}' not accepted here: use {accepted}")
        return None
    return units[unit]


def _numbers(columns, samples, add) -> np.ndarray:
    """The cells as numbers `(rows, columns)`: NaN for an empty cell; a problem
    for text that is not a number, or an infinite number."""
    values = np.full((len(samples), len(columns)), np.nan)
    bad: dict[int, list[str]] = {}
    for r, (number, cells) in enumerate(samples):
        for c, cell in enumerate(cells[: len(columns)]):
            if columns[c] is None:
                continue
            text = cell.strip()
            if not text:
                continue
            try:
                value = float(text)
            except ValueError:
                bad.setdefault(c, []).append(
                    f"line {number}: not a number: {shown(cell)}"
                )
                continue
            if math.isinf(value):
                bad.setdefault(c, []).append(
                    f"line {number}: infinite value {shown(cell)} (leave a missing "
                    f"sample empty)"
                )
                continue
            too_large = magnitude_problem(value, columns[c].factor)
            if too_large:
                bad.setdefault(c, []).append(f"line {number}: {too_large}")
                continue
            values[r, c] = value * columns[c].factor
    for c, messages in bad.items():
        for message in messages[:MAX_CELL_PROBLEMS]:
            row, _, text = message.partition(": ")
            add(columns[c].label, row, text)
        if len(messages) > MAX_CELL_PROBLEMS:
            add(
                columns[c].label,
                "",
                f"and {len(messages) - MAX_CELL_PROBLEMS} more cells that are not "
                f"finite numbers",
            )
    return values


def _times(columns, samples, values, scenario, add) -> np.ndarray | None:
    if not columns or columns[0] is None:
        return None
    if columns[0].kind != "time":
        grid = np.asarray(scenario.ts)
        if len(grid) != len(samples):
            add(
                "",
                "",
                f"without a time column the samples are taken at the scenario's "
                f"[time] grid of {len(grid)} times, but the file has {len(samples)} "
                f"rows of samples; add a column 't' [s]",
            )
            return None
        return grid
    label, times = columns[0].label, values[:, 0]
    for r in np.flatnonzero(np.isnan(times))[:MAX_CELL_PROBLEMS]:
        add(label, f"line {samples[r][0]}", "the time is missing")
    steps = np.diff(times)
    for r in np.flatnonzero(~(steps > 0) & np.isfinite(steps))[:MAX_CELL_PROBLEMS]:
        add(
            label,
            f"line {samples[r + 1][0]}",
            f"times must increase: t = {times[r + 1]:g} s follows t = {times[r]:g} s",
        )
    return times


def _noise(columns, noise, add) -> dict[int, float]:
    """Noise level per column index (SI units) from the `sigma` row."""
    number, cells = noise
    out = {}
    for c, column in enumerate(columns):
        if column.kind == "time" or c >= len(cells):
            continue
        text = cells[c].strip()
        if column.kind == "force":
            if text:
                add(
                    column.label,
                    f"line {number} ({NOISE_ROW})",
                    "forces are known inputs: leave their noise cell empty",
                )
            continue
        try:
            value = float(text) * column.factor
        except ValueError:
            add(
                column.label,
                f"line {number} ({NOISE_ROW})",
                f"the noise level must be a positive number, got {shown(cells[c])}"
                + (" (give one for every measured column)" if not text else ""),
            )
            continue
        if not (math.isfinite(value) and value > 0):
            add(
                column.label,
                f"line {number} ({NOISE_ROW})",
                f"the noise level must be a positive number, got {shown(cells[c])}",
            )
            continue
        too_large = magnitude_problem(value)
        if too_large or value < 1 / MAX_MAGNITUDE:
            add(
                column.label,
                f"line {number} ({NOISE_ROW})",
                too_large
                or f"the noise level {shown(cells[c].strip())} lies below "
                f"{1 / MAX_MAGNITUDE:g} in SI units, the smallest accepted",
            )
            continue
        out[c] = value
    return out


def _check_complete(columns, values, scenario, add) -> None:
    """Every coordinate of every body measured (a column with at least one value);
    velocity columns all or none; forces with no empty cell."""
    names = list(scenario.names)
    coords = coordinate_names(scenario.model.convention)
    found = {
        kind: {(c.body, c.index) for c in columns if c.kind == kind}
        for kind in ("y", "ydot")
    }
    for kind, prefix in (("y", ""), ("ydot", "ydot.")):
        if kind == "ydot" and not found[kind]:
            continue
        missing = [
            f"{prefix}{b}.{c}"
            for i, b in enumerate(names)
            for k, c in enumerate(coords)
            if (i, k) not in found[kind]
        ]
        if missing:
            add(
                "",
                "",
                f"missing column{'s' if len(missing) > 1 else ''} "
                f"{', '.join(missing)}: every coordinate of every body needs a "
                + (
                    "column"
                    if kind == "y"
                    else "velocity column once one is given (all or none)"
                ),
            )
    for c, column in enumerate(columns):
        if column.kind in ("y", "ydot") and np.all(np.isnan(values[:, c])):
            add(column.label, "", "holds no value (every cell is empty)")
        if column.kind == "force" and np.any(np.isnan(values[:, c])):
            add(
                column.label,
                "",
                "forces are inputs of the simulation: a force column needs a value "
                "in every row",
            )


def _assemble(columns, values, times, sigma, n_bodies) -> MeasuredData:
    shape = (len(times), n_bodies, 6)
    y, ydot, forces = np.full(shape, np.nan), None, None
    sig = np.ones((n_bodies, 6)) if sigma is not None else None
    sig_dot = None
    for c, column in enumerate(columns):
        if column.kind == "y":
            y[:, column.body, column.index] = values[:, c]
            if sig is not None:
                sig[column.body, column.index] = sigma[c]
        elif column.kind == "ydot":
            if ydot is None:
                ydot = np.full(shape, np.nan)
                sig_dot = np.ones((n_bodies, 6)) if sigma is not None else None
            ydot[:, column.body, column.index] = values[:, c]
            if sig_dot is not None:
                sig_dot[column.body, column.index] = sigma[c]
        elif column.kind == "force":
            if forces is None:
                forces = np.zeros(shape)
            forces[:, column.body, column.index] = values[:, c]
    on_object = any(c.kind == "force" and c.body == 0 for c in columns)
    return MeasuredData(times, y, ydot, sig, sig_dot, forces, on_object)
