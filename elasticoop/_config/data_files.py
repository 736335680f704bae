"""Data files a scenario refers to: matrices (.npy, .csv) and CSV time series.

Paths are relative to the scenario file's folder. Every reader raises `ValueError`
with a message meant to follow "table [...], key '...': ". A file larger than
`MAX_DATA_FILE_BYTES` is refused before it is read.
"""

import pathlib
import warnings

import numpy as np

from .limits import (
    MAX_DATA_FILE_BYTES,
    MAX_MAGNITUDE,
    format_bytes,
    magnitude_problem,
)

TIME_COLUMNS = ("t", "time")


def _as_written(cell) -> str:
    """A cell of a CSV file as its text (pandas reads true and false as booleans)."""
    if isinstance(cell, bool | np.bool_):
        return str(bool(cell)).lower()
    return str(cell).strip()


def resolve(base_dir: pathlib.Path, name: str) -> pathlib.Path:
    path = pathlib.Path(name).expanduser()
    return path if path.is_absolute() else base_dir / path


def existing_file(base_dir: pathlib.Path, name: str) -> pathlib.Path:
    """The path of data file `name`: it must be a file (not a folder) of at most
    `MAX_DATA_FILE_BYTES`."""
    path = resolve(base_dir, name)
    if path.is_dir():
        raise ValueError(f"'{name}' is a folder, not a data file (at {path})")
    if not path.is_file():
        raise ValueError(f"file '{name}' not found (looked for {path})")
    size = path.stat().st_size
    if size > MAX_DATA_FILE_BYTES:
        raise ValueError(
            f"file '{name}' holds {format_bytes(size)}, over the limit of "
            f"{format_bytes(MAX_DATA_FILE_BYTES)} for a data file"
        )
    if size == 0:
        raise ValueError(f"file '{name}' is empty")
    return path


def _read_npy(path: pathlib.Path, name: str) -> np.ndarray:
    """A numeric array from a .npy file, its header checked before the data is read
    (a file without the NumPy header, or of Python objects, is refused)."""
    fmt = np.lib.format
    with open(path, "rb") as file:
        try:
            version = fmt.read_magic(file)
        except ValueError:
            raise ValueError(
                f"file '{name}' is not a .npy file (it does not start with the NumPy "
                f"format's header)"
            ) from None
        if version not in ((1, 0), (2, 0)):  # 3.0: structured (named) fields only
            raise ValueError(
                f"file '{name}' is a .npy file of format version "
                f"{version[0]}.{version[1]}, which holds structured data, not a "
                f"matrix of numbers"
            )
        if version == (1, 0):
            read_header = fmt.read_array_header_1_0
        else:
            read_header = fmt.read_array_header_2_0
        try:
            shape, _, dtype = read_header(file)
        except ValueError as err:
            raise ValueError(
                f"file '{name}' has a damaged .npy header ({err})"
            ) from None
    if dtype.hasobject:
        raise ValueError(
            f"file '{name}' holds Python objects (dtype {dtype}), not numbers"
        )
    if not (np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)):
        what = "complex numbers" if np.issubdtype(dtype, np.complexfloating) else ""
        raise ValueError(
            f"file '{name}' holds {what or f'entries of dtype {dtype}'}, not real "
            f"numbers"
        )
    if len(shape) != 2:
        raise ValueError(f"file '{name}' holds an array of shape {shape}, not 2-D")
    try:
        return np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise ValueError(
            f"file '{name}' is damaged or truncated: its header announces an array "
            f"of shape {shape} ({err})"
        ) from None


def _read_csv_matrix(path: pathlib.Path, name: str) -> np.ndarray:
    """A 2-D array from a comma-separated file of numbers without header."""
    try:
        with warnings.catch_warnings():
            # an empty file is reported below, not warned about
            warnings.simplefilter("ignore", UserWarning)
            arr = np.loadtxt(
                path, delimiter=",", ndmin=2, comments="#", encoding="utf-8-sig"
            )
    except UnicodeDecodeError:
        raise ValueError(f"file '{name}' is not a text file (not UTF-8)") from None
    except ValueError as err:
        raise ValueError(f"file '{name}' could not be read as numbers: {err}") from None
    if arr.size == 0:
        raise ValueError(f"file '{name}' holds no numbers")
    return arr


def read_matrix(base_dir: pathlib.Path, name: str) -> np.ndarray:
    """A 2-D float64 array from a .npy file or a comma-separated .csv without header."""
    path = existing_file(base_dir, name)
    suffix = path.suffix.lower()
    if suffix not in (".npy", ".csv", ".txt"):
        raise ValueError(f"file '{name}': use a .npy or .csv file")
    try:
        if suffix == ".npy":
            arr = _read_npy(path, name)
        else:
            arr = _read_csv_matrix(path, name)
    except OSError as err:
        raise ValueError(f"file '{name}' could not be read: {err}") from None
    if arr.ndim != 2:
        raise ValueError(f"file '{name}' holds an array of shape {arr.shape}, not 2-D")
    arr = arr.astype(np.float64)
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"file '{name}' holds NaN or infinite entries")
    huge = np.argwhere(np.abs(arr) > MAX_MAGNITUDE)
    if huge.size:
        r, c = (int(i) for i in huge[0])
        raise ValueError(
            f"file '{name}', entry [{r}][{c}]: {magnitude_problem(float(arr[r, c]))}"
        )
    return arr


def read_series(base_dir: pathlib.Path, name: str):
    """Samples from a CSV file with a header row: a time column `t` (or `time`) [s],
    strictly increasing, then named numeric columns.

    **Returns:** `(times, {column: values})` as float64 arrays.
    """
    import pandas as pd

    path = existing_file(base_dir, name)
    try:
        frame = pd.read_csv(path, comment="#", skipinitialspace=True)
    except OSError as err:
        raise ValueError(f"file '{name}' could not be read: {err}") from None
    except UnicodeDecodeError:
        raise ValueError(f"file '{name}' is not a text file (not UTF-8)") from None
    except (ValueError, pd.errors.ParserError) as err:
        message = str(err).strip().splitlines()[0] if str(err).strip() else "empty"
        raise ValueError(f"file '{name}' is not a readable CSV ({message})") from None
    columns = [str(c).strip() for c in frame.columns]
    if not columns or columns[0] not in TIME_COLUMNS:
        raise ValueError(
            f"file '{name}': the first column must be the time 't' [s], got "
            f"{columns[0] if columns else 'no columns'!r}"
        )
    # pandas renames a repeated name ('fz', 'fz.1'): read the header as written
    header = pd.read_csv(
        path, comment="#", skipinitialspace=True, header=None, nrows=1, dtype=str
    )
    written = ["" if pd.isna(c) else str(c).strip() for c in header.iloc[0]]
    if "" in written:
        raise ValueError(
            f"file '{name}': column {written.index('') + 1} of the header has no name"
        )
    repeated = sorted({c for c in written if written.count(c) > 1})
    if repeated:
        raise ValueError(
            f"file '{name}' has repeated column names: {', '.join(repeated)}"
        )
    if len(frame) < 2:
        rows = "no rows of samples, only a header" if len(frame) == 0 else "1 row"
        raise ValueError(
            f"file '{name}' has {rows}: it needs at least 2 rows of samples"
        )
    bad = [
        c
        for c, col in zip(columns, frame.columns)
        if not pd.api.types.is_numeric_dtype(frame[col])
        or pd.api.types.is_bool_dtype(frame[col])
    ]
    if bad:
        cells = frame[frame.columns[columns.index(bad[0])]]
        # (true and false: a column of booleans, each of its cells wrong)
        wrong = cells.notna() & (
            pd.to_numeric(cells, errors="coerce").isna()
            | pd.api.types.is_bool_dtype(cells)
        )
        row = int(np.flatnonzero(wrong.to_numpy())[0]) if wrong.any() else None
        raise ValueError(
            f"file '{name}', column '{bad[0]}': holds non-numbers"
            if row is None
            else f"file '{name}', column '{bad[0]}', data row {row + 1}: not a "
            f"number: {_as_written(cells.iloc[row])!r}"
        )
    values = frame.to_numpy(dtype=np.float64)
    if not np.all(np.isfinite(values)):
        row = int(np.argwhere(~np.isfinite(values))[0, 0])
        raise ValueError(
            f"file '{name}' has an empty, NaN or infinite entry in data row {row + 1}"
        )
    huge = np.argwhere(np.abs(values) > MAX_MAGNITUDE)
    if huge.size:
        row, column = (int(i) for i in huge[0])
        raise ValueError(
            f"file '{name}', column '{columns[column]}', data row {row + 1}: "
            f"{magnitude_problem(float(values[row, column]))}"
        )
    times = values[:, 0]
    if not np.all(np.diff(times) > 0):
        raise ValueError(f"file '{name}': times must be strictly increasing")
    return times, {c: values[:, k] for k, c in enumerate(columns) if k > 0}
