"""Measured motion read from a data file (CSV or netCDF) into an `Experiment`.

The file gives the samples; the scenario gives the model's names and convention,
the initial state the simulation starts from, and, unless the file has force
columns, the applied forces (and, for a CSV file without a time column, the time
grid). The formats are described in `docs/data_files.md`.
"""

import pathlib

import numpy as np

from .._forces import SampledForce
from .._identify import Experiment
from .data_files import existing_file
from .measured_csv import read_measured_csv
from .measured_netcdf import read_measured_netcdf
from .measured_samples import MeasuredData
from .problems import DataFileError, DataProblem

CSV_SUFFIXES = (".csv", ".txt")
NETCDF_SUFFIXES = (".nc", ".nc4", ".netcdf", ".h5")


def load_experiment(path, scenario, *, velocities: bool = True) -> Experiment:
    """Read measured motion from a data file into an `Experiment` for `identify`.

    **Arguments:**

    - `path`: a CSV file (`.csv`, `.txt`) or a netCDF file (`.nc`, e.g. the
      `trajectory.nc` that `elasticoop run` writes).
    - `scenario`: the `Scenario` the data belongs to (`load_scenario`): its body
      names, coordinate names and Euler convention name the file's columns; the
      simulation starts from its initial state at the file's first time; its
      forces apply unless the file gives force columns; and its `[time]` grid is
      the sample times of a CSV file without a time column.
    - `velocities`: use the velocity samples of the file (CSV `ydot.` columns,
      netCDF variable `ydot`) as measurements too (default `True`).

    Every problem of the file is collected, and one `DataFileError` (a
    `ValueError`) lists them all, each naming the file, the column and the line
    (CSV) or sample (netCDF).

    **Returns:** an `Experiment`.
    """
    source = str(path)
    path = pathlib.Path(path)

    def refuse(message: str) -> DataFileError:
        return DataFileError(source, [DataProblem("", "", message)])

    if scenario.prescribed is not None:
        raise refuse(
            f"scenario '{scenario.name}' prescribes coordinates ([prescribed]); "
            f"identification simulates the free motion and cannot use it"
        )
    try:
        existing_file(pathlib.Path("."), str(path))
    except ValueError as err:
        raise refuse(str(err)) from None
    suffix = path.suffix.lower()
    if suffix in CSV_SUFFIXES:
        data = read_measured_csv(path, source, scenario)
    elif suffix in NETCDF_SUFFIXES:
        data = read_measured_netcdf(path, source, scenario)
    else:
        raise refuse(
            f"unknown kind of data file '{path.suffix}': use a CSV file "
            f"({', '.join(CSV_SUFFIXES)}) or a netCDF file "
            f"({', '.join(NETCDF_SUFFIXES)})"
        )
    return _experiment(data, scenario, source, velocities)


def _experiment(data: MeasuredData, scenario, source, velocities) -> Experiment:
    _check_overlap(data, scenario, source)
    forces = scenario.forces
    if data.forces is not None:
        rows = data.forces if data.force_on_object else data.forces[:, 1:]
        forces = SampledForce(data.ts, rows)
    ydot = data.ydot if velocities else None
    sigma_ydot = data.sigma_ydot if velocities else None
    try:
        return Experiment(
            data.ts,
            data.y,
            scenario.y_init,
            scenario.ydot_init,
            forces=forces,
            sigma=data.sigma,
            ydot=ydot,
            sigma_ydot=sigma_ydot,
            # a scenario that starts at rest in its equilibrium: the experiment
            # too (the contact bodies held at their poses)
            rest=getattr(scenario, "initial_from", None) == "equilibrium" or None,
        )
    except ValueError as err:
        raise DataFileError(
            source,
            [DataProblem("", "", f"the samples cannot form an experiment: {err}")],
        ) from None


def _check_overlap(data: MeasuredData, scenario, source) -> None:
    """The data's time span must overlap the scenario's `[time]` span (the
    simulation starts from the scenario's initial state at the data's first time,
    under the scenario's forces)."""
    ts = np.asarray(data.ts)
    start, stop = float(scenario.ts[0]), float(scenario.ts[-1])
    first, last = float(ts[0]), float(ts[-1])
    if last < start or first > stop:
        raise DataFileError(
            source,
            [
                DataProblem(
                    "t",
                    "",
                    f"the data's times {first:g} to {last:g} s do not overlap the "
                    f"scenario's [time] span {start:g} to {stop:g} s (scenario "
                    f"'{scenario.name}'): the data belong to another time axis",
                )
            ],
        )
