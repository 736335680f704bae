"""Bounds on what a scenario file may ask for, checked before anything is allocated:
an oversized request is a problem of the scenario, named by its table and key, not
an out-of-memory crash of the run that follows.

- `MAX_SCENARIO_FILE_BYTES`: the TOML file itself (16 MiB).
- `MAX_DATA_FILE_BYTES`: one data file it refers to, CSV or .npy (1 GiB).
- `MAX_SAMPLES_BYTES`: the samples built from one CSV time series, forces
  `(rows, bodies, 6)` or prescribed motion (1 GiB of float64).
- `MAX_OUTPUT_BYTES`: the results of one run, `output_bytes` (1 GiB of float64).
"""

from .._sizes import format_bytes as format_bytes

MAX_SCENARIO_FILE_BYTES = 16 * 2**20
MAX_DATA_FILE_BYTES = 2**30
MAX_SAMPLES_BYTES = 2**30
MAX_OUTPUT_BYTES = 2**30

FLOAT_BYTES = 8


def output_numbers_per_sample(
    n_bodies: int, n_connections: int, prescribed: bool
) -> int:
    """How many float64 numbers one output sample of a run holds in its results: the
    time, $Y$, $\\dot Y$ and $\\partial\\Pi/\\partial Y$ (`6 * bodies` each), the
    reactions of prescribed coordinates (`6 * bodies`), six energies, and one
    elastic wrench per connection (6 each)."""
    per_body = 3 + (1 if prescribed else 0)
    return 1 + 6 * n_bodies * per_body + 6 + 6 * n_connections


def output_bytes(
    samples: int, n_bodies: int, n_connections: int, prescribed: bool
) -> int:
    """Bytes of the results of a run with `samples` output times."""
    numbers = output_numbers_per_sample(n_bodies, n_connections, prescribed)
    return samples * numbers * FLOAT_BYTES


def output_limit_problem(
    samples: int, n_bodies: int, n_connections: int, prescribed: bool = False
) -> str | None:
    """Why the results of a run with `samples` output times (with the bodies and
    connections given) do not fit `MAX_OUTPUT_BYTES`, in words; `None` when they
    fit. Checked before the output times are made."""
    size = output_bytes(samples, n_bodies, n_connections, prescribed)
    if size <= MAX_OUTPUT_BYTES:
        return None
    per_sample = output_numbers_per_sample(n_bodies, n_connections, prescribed)
    most = MAX_OUTPUT_BYTES // (FLOAT_BYTES * per_sample)
    return (
        f"the results of one run would need {format_bytes(size)} for samples = "
        f"{samples} ({per_sample} float64 numbers per output time for {n_bodies} "
        f"bod{'y' if n_bodies == 1 else 'ies'} and {n_connections} "
        f"connection{'' if n_connections == 1 else 's'}), over the limit of "
        f"{format_bytes(MAX_OUTPUT_BYTES)}; use at most {most} samples"
    )


# What `elasticoop run` writes, at most, besides the numbers of its results: a
# float64 in trajectory.csv takes up to 24 characters ("-1.2345678901234567e-05")
# and its comma; trajectory.nc holds 8 bytes per number plus its layout and the
# model's parameters; the summary and the four PNG plots.
CSV_BYTES_PER_NUMBER = 25
NETCDF_LAYOUT_BYTES = 64 * 2**10
SUMMARY_BYTES = 64 * 2**10
PLOTS_BYTES = 2 * 2**20


def run_file_numbers_per_sample(
    n_bodies: int, n_connections: int, prescribed: bool
) -> int:
    """Numbers per output sample in `trajectory.nc` and `trajectory.csv`: those of
    `output_numbers_per_sample` and the applied forces (`6 * bodies`)."""
    return output_numbers_per_sample(n_bodies, n_connections, prescribed) + 6 * n_bodies


def run_files_bytes(
    samples: int, n_bodies: int, n_connections: int, prescribed: bool, plots: bool
) -> dict[str, int]:
    """The most bytes each file of a run takes on disk: `trajectory.nc`,
    `trajectory.csv`, `summary.json` and (with `plots`) the plots; the disk a run
    needs is their sum."""
    numbers = samples * run_file_numbers_per_sample(n_bodies, n_connections, prescribed)
    sizes = {
        "trajectory.nc": numbers * FLOAT_BYTES + NETCDF_LAYOUT_BYTES,
        "trajectory.csv": numbers * CSV_BYTES_PER_NUMBER,
        "summary.json": SUMMARY_BYTES,
    }
    if plots:
        sizes["plots"] = PLOTS_BYTES
    return sizes


# The largest magnitude of a number in a scenario file or a data file, in SI units
# (kg, m, s, N, rad): beyond it the products the simulation forms (weights,
# energies, squared residuals) leave float64's range, and no physical quantity of
# a manipulation task comes near it.
MAX_MAGNITUDE = 1e15


def magnitude_problem(value: float, factor: float = 1.0) -> str | None:
    """A message when `value` (times `factor`, its unit's factor to SI) lies beyond
    `MAX_MAGNITUDE`; `None` when it does not, or is not finite (checked apart)."""
    import math

    if not math.isfinite(value) or abs(value * factor) <= MAX_MAGNITUDE:
        return None
    return (
        f"{value!r} lies beyond ±{MAX_MAGNITUDE:g}, the largest magnitude accepted "
        "(in SI units)"
    )
