"""Data files a scenario refers to: matrices (.npy, .csv) and CSV time series.

Paths are relative to the scenario file's folder. Every reader raises `ValueError`
with a message meant to follow "table [...], key '...': ".
"""

import pathlib

import numpy as np

TIME_COLUMNS = ("t", "time")


def resolve(base_dir: pathlib.Path, name: str) -> pathlib.Path:
    path = pathlib.Path(name).expanduser()
    return path if path.is_absolute() else base_dir / path


def read_matrix(base_dir: pathlib.Path, name: str) -> np.ndarray:
    """A 2-D float64 array from a .npy file or a comma-separated .csv without header."""
    path = resolve(base_dir, name)
    if not path.is_file():
        raise ValueError(f"file '{name}' not found (looked for {path})")
    suffix = path.suffix.lower()
    try:
        if suffix == ".npy":
            arr = np.load(path, allow_pickle=False)
        elif suffix in (".csv", ".txt"):
            arr = np.loadtxt(path, delimiter=",", ndmin=2, comments="#")
        else:
            raise ValueError(f"file '{name}': use a .npy or .csv file")
    except OSError as err:
        raise ValueError(f"file '{name}' could not be read: {err}") from None
    except ValueError as err:
        if str(err).startswith("file"):
            raise
        raise ValueError(f"file '{name}' could not be read as numbers: {err}") from None
    if arr.ndim != 2:
        raise ValueError(f"file '{name}' holds an array of shape {arr.shape}, not 2-D")
    try:
        arr = arr.astype(np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"file '{name}' does not hold numbers") from None
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"file '{name}' holds NaN or infinite entries")
    return arr


def read_series(base_dir: pathlib.Path, name: str):
    """Samples from a CSV file with a header row: a time column `t` (or `time`) [s],
    strictly increasing, then named numeric columns.

    **Returns:** `(times, {column: values})` as float64 arrays.
    """
    import pandas as pd

    path = resolve(base_dir, name)
    if not path.is_file():
        raise ValueError(f"file '{name}' not found (looked for {path})")
    try:
        frame = pd.read_csv(path, comment="#", skipinitialspace=True)
    except OSError as err:
        raise ValueError(f"file '{name}' could not be read: {err}") from None
    except (ValueError, pd.errors.ParserError) as err:
        message = str(err).strip().splitlines()[0] if str(err).strip() else "empty"
        raise ValueError(f"file '{name}' is not a readable CSV ({message})") from None
    columns = [str(c).strip() for c in frame.columns]
    if not columns or columns[0] not in TIME_COLUMNS:
        raise ValueError(
            f"file '{name}': the first column must be the time 't' [s], got "
            f"{columns[0] if columns else 'no columns'!r}"
        )
    if len(set(columns)) != len(columns):
        raise ValueError(f"file '{name}' has repeated column names")
    bad = [
        c
        for c, col in zip(columns, frame.columns)
        if not pd.api.types.is_numeric_dtype(frame[col])
    ]
    if bad:
        raise ValueError(f"file '{name}': column '{bad[0]}' holds non-numbers")
    values = frame.to_numpy(dtype=np.float64)
    if values.shape[0] < 2:
        raise ValueError(f"file '{name}' needs at least 2 rows of samples")
    if not np.all(np.isfinite(values)):
        row = int(np.argwhere(~np.isfinite(values))[0, 0])
        raise ValueError(
            f"file '{name}' has an empty, NaN or infinite entry in data row {row + 1}"
        )
    times = values[:, 0]
    if not np.all(np.diff(times) > 0):
        raise ValueError(f"file '{name}': times must be strictly increasing")
    return times, {c: values[:, k] for k, c in enumerate(columns) if k > 0}
