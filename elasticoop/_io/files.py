"""Writing a run's results into a folder.

The netCDF file is made in memory and written with ordinary file writes: HDF5
writing straight to a file that fails (a full disk, a file-size limit) leaves
the library in a state that crashes the process (signal 11), where a failed
ordinary write is an `OSError` that leaves the earlier results alone.
"""

import errno
import os
import pathlib
import shutil

from .._config.limits import format_bytes
from .strict_json import strict_json
from .xarray import dataset_to_frame


def free_bytes(path) -> int:
    """Bytes free to this user on the file system of `path` (or of the nearest
    folder above it that exists)."""
    path = pathlib.Path(path)
    while not path.exists() and path != path.parent:
        path = path.parent
    return shutil.disk_usage(path).free


def ensure_free_space(path, needed: int, what: str) -> None:
    """Raise `OSError` (`ENOSPC`) naming `what` and both sizes unless `needed`
    bytes are free where `path` lies."""
    free = free_bytes(path)
    if needed > free:
        raise OSError(
            errno.ENOSPC,
            f"No space left on device: {what} need {format_bytes(needed)} but "
            f"{format_bytes(free)} are free",
            str(path),
        )


def write_bytes(path: pathlib.Path, data) -> None:
    """Write `data` (bytes-like) into a new file `path`."""
    with open(path, "wb") as file:
        file.write(data)
        file.flush()
        os.fsync(file.fileno())


def write_outputs(ds, summary: dict, outdir) -> dict[str, pathlib.Path]:
    """Write `trajectory.nc` (netCDF4 via h5netcdf), `trajectory.csv` and
    `summary.json` into `outdir` (created if needed); returns the paths.

    The netCDF file is made in memory first (see the module's docstring), and its
    size is checked against the free space before anything is written. A failed
    write raises `OSError`.

    `summary.json` is strict JSON: a number that is not finite (NaN, +-inf) is
    written as `null`."""
    outdir = pathlib.Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = {
        "netcdf": outdir / "trajectory.nc",
        "csv": outdir / "trajectory.csv",
        "summary": outdir / "summary.json",
    }
    netcdf = ds.to_netcdf(engine="h5netcdf")  # in memory
    ensure_free_space(outdir, len(netcdf), "trajectory.nc's bytes")
    write_bytes(paths["netcdf"], netcdf)
    del netcdf
    dataset_to_frame(ds).to_csv(paths["csv"], index=False)
    paths["summary"].write_text(strict_json(summary))
    return paths
