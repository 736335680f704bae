"""The samples of a measured-data file, in the scenario's order and units."""

import dataclasses

import numpy as np

from .limits import MAX_SAMPLES_BYTES, format_bytes


@dataclasses.dataclass
class MeasuredData:
    """The samples of one data file in the scenario's order and SI units (angles
    in radians), before they become an `Experiment`.

    - `ts`: sample times [s], `(times,)`.
    - `y`, `ydot`: $Y$ and (or `None`) $\\dot Y$, `(times, bodies, 6)`, NaN where a
      sample is missing.
    - `sigma`, `sigma_ydot`: noise levels `(bodies, 6)`, or `None`.
    - `forces`: applied forces `(times, bodies, 6)` from the file, or `None`;
      `force_on_object`: whether the file gives forces on the object (row 0).
    """

    ts: np.ndarray
    y: np.ndarray
    ydot: np.ndarray | None = None
    sigma: np.ndarray | None = None
    sigma_ydot: np.ndarray | None = None
    forces: np.ndarray | None = None
    force_on_object: bool = False


def check_samples_size(n_rows: int, n_bodies: int) -> str | None:
    """A message when `(rows, bodies, 6)` samples exceed `MAX_SAMPLES_BYTES`."""
    size = n_rows * n_bodies * 6 * 8
    if size <= MAX_SAMPLES_BYTES:
        return None
    return (
        f"{n_rows} samples of {n_bodies} bodies need {format_bytes(size)}, over the "
        f"limit of {format_bytes(MAX_SAMPLES_BYTES)}; resample the file"
    )
