"""Writing a run's results into a folder."""

import pathlib

from .strict_json import strict_json
from .xarray import dataset_to_frame


def write_outputs(ds, summary: dict, outdir) -> dict[str, pathlib.Path]:
    """Write `trajectory.nc` (netCDF4 via h5netcdf), `trajectory.csv` and
    `summary.json` into `outdir` (created if needed); returns the paths.

    `summary.json` is strict JSON: a number that is not finite (NaN, +-inf) is
    written as `null`."""
    outdir = pathlib.Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    paths = {
        "netcdf": outdir / "trajectory.nc",
        "csv": outdir / "trajectory.csv",
        "summary": outdir / "summary.json",
    }
    ds.to_netcdf(paths["netcdf"], engine="h5netcdf")
    dataset_to_frame(ds).to_csv(paths["csv"], index=False)
    paths["summary"].write_text(strict_json(summary))
    return paths
