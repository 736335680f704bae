"""A trajectory as data a researcher can open: an xarray Dataset (netCDF) and a
wide table (CSV)."""

from typing import TYPE_CHECKING

import equinox as eqx
import numpy as np

from .._forces import check_force
from .._models import ImmobileModel, MobileModel
from .._naming import (
    body_names as _body_names,
    connection_names as _conn_names,
    coordinate_names,
    dof_names,
)
from .._status import status_message
from .._version import __version__

if TYPE_CHECKING:
    import pandas
    import xarray

# (translation, rotation) units of the per-coordinate variables.
_UNITS = {
    "y": ("m", "rad"),
    "ydot": ("m/s", "rad/s"),
    "elastic_force": ("N", "N m"),
    "elastic_wrench": ("N", "N m"),
    "reaction": ("N", "N m"),
    "applied_force": ("N", "N m"),
}
_ENERGIES = {
    "kinetic_energy": "kinetic energy T",
    "elastic_energy": "elastic potential energy Pi",
    "gravity_energy": "gravity potential energy sum m_i g z_i",
    "work": "work of the applied forces since t0",
    "dissipated": "energy dissipated since t0",
    "energy_residual": "E - E(t0) - work + dissipated (zero up to solver error)",
}


def trajectory_to_xarray(
    traj, body_names=None, connection_names=None, attrs=None, forces=None
) -> "xarray.Dataset":
    """The trajectory as an `xarray.Dataset`.

    Dimensions `time` [s], `body` (named), `coordinate` ($x, y, z$ and the
    convention's Euler angles; the non-dimension coordinate `coordinate_unit` gives
    m or rad), and for a `MobileModel` `connection` (named `"<i>-<j>"` by default).

    **Variables:** `y`, `ydot` $(t, body, coordinate)$; the energies
    `kinetic_energy`, `elastic_energy`, `gravity_energy`, `work`, `dissipated`,
    `energy_residual` [J]; `elastic_force` $\\partial\\Pi/\\partial Y$;
    `elastic_wrench` per connection (`MobileModel`); `reaction` when the trajectory
    has one; and the model's parameters (`mass`, `inertia`, `stiffness`, `damping`,
    `rest_length`, `rest_angles`, or `K`, `D`, `y0`). Every variable has `units`
    and `long_name` attributes; the Dataset's attributes hold the model kind,
    convention, gravity, status and whatever `attrs` adds (scalars and strings).

    **Arguments:**

    - `traj`: a single (un-batched) `Trajectory`.
    - `body_names`: names of the bodies (default `object, contact1, ...`).
    - `connection_names`: names of the connections (default `"<i>-<j>"` with body
      names).
    - `attrs`: extra global attributes.
    - `forces`: the applied forces of the run, in any form `simulate` takes
      (an array `(m, 6)`, an `AbstractForce` such as a scenario's, or a callable):
      adds `applied_force`, $F(t, Y, \\dot Y)$ at the saved samples on every body
      (zero rows for bodies without a force).
    """
    import xarray as xr

    if np.ndim(traj.ts) != 1:
        raise ValueError(
            "to_xarray needs a single trajectory (ts of shape (times,)), got ts of "
            f"shape {np.shape(traj.ts)}; index the batch first"
        )
    model = traj.model
    n = model.n_bodies
    bodies = _body_names(body_names, n)
    coords = coordinate_names(model.convention)
    coordinate_unit = ["m"] * 3 + ["rad"] * 3
    ds = xr.Dataset(
        coords={
            "time": ("time", np.asarray(traj.ts), {"units": "s", "long_name": "time"}),
            "body": ("body", list(bodies)),
            "coordinate": ("coordinate", list(coords)),
            "coordinate_unit": ("coordinate", coordinate_unit),
        }
    )

    def per_coordinate(name, values, long_name, dims=("time", "body", "coordinate")):
        t, r = _UNITS[name]
        angles = ", ".join(coords[3:])
        ds[name] = (
            dims,
            np.asarray(values),
            {"long_name": long_name, "units": f"{t} (x, y, z); {r} ({angles})"},
        )

    per_coordinate("y", traj.y, "generalized coordinates Y")
    per_coordinate("ydot", traj.ydot, "generalized velocities dY/dt")
    energies = {
        "kinetic_energy": traj.kinetic_energy(),
        "elastic_energy": traj.elastic_energy(),
        "gravity_energy": traj.gravity_energy(),
        "work": traj.work,
        "dissipated": traj.dissipated,
        "energy_residual": traj.energy_residual(),
    }
    for name, values in energies.items():
        ds[name] = (
            "time",
            np.asarray(values),
            {"long_name": _ENERGIES[name], "units": "J"},
        )
    per_coordinate("elastic_force", traj.elastic_forces(), "elastic force dPi/dY")
    if forces is not None:
        per_coordinate(
            "applied_force",
            applied_forces(forces, traj),
            "generalized force applied by the manipulators (and on the object)",
        )
    if traj.reaction is not None:
        per_coordinate(
            "reaction", traj.reaction, "generalized force holding the prescribed motion"
        )

    ds["mass"] = ("body", np.asarray(model.bodies.mass), {"units": "kg"})
    ds["inertia"] = (
        ("body", "principal_axis"),
        np.asarray(model.bodies.inertia),
        {"units": "kg m^2", "long_name": "principal moments of inertia A, B, C"},
    )
    ds = ds.assign_coords(principal_axis=["A", "B", "C"])
    conns = None
    if isinstance(model, MobileModel):
        pairs = np.asarray(model.pairs)
        conns = _conn_names(connection_names, pairs, bodies)
        ds = ds.assign_coords(
            connection=list(conns),
            body_i=("connection", [bodies[i] for i in pairs[:, 0]]),
            body_j=("connection", [bodies[j] for j in pairs[:, 1]]),
            angle=list(coords[3:]),
        )
        per_coordinate(
            "elastic_wrench",
            traj.elastic_wrench(),
            "elastic wrench of each connection on body_i, -dPi_ij/dY_i",
            dims=("time", "connection", "coordinate"),
        )
        for name, units in (
            ("stiffness", "N/m; N m/rad"),
            ("damping", "N s/m; N m s/rad"),
        ):
            ds[name] = (
                ("connection", "coordinate"),
                np.asarray(getattr(model, name)),
                {"units": units},
            )
        ds["rest_length"] = (
            "connection",
            np.asarray(model.rest_length),
            {"units": "m"},
        )
        ds["rest_angles"] = (
            ("connection", "angle"),
            np.asarray(model.rest_angles),
            {"units": "rad"},
        )
    elif isinstance(model, ImmobileModel):
        dof = dof_names(bodies, model.convention)
        ds = ds.assign_coords(dof=dof, dof_col=dof)
        ds["K"] = (
            ("dof", "dof_col"),
            np.asarray(model.K),
            {"units": "N/m, N, N m/rad (by block)", "long_name": "stiffness matrix"},
        )
        ds["D"] = (
            ("dof", "dof_col"),
            np.asarray(model.D),
            {
                "units": "N s/m, N s, N m s/rad (by block)",
                "long_name": "damping matrix",
            },
        )
        ds["y0"] = (
            ("body", "coordinate"),
            np.asarray(model.y0),
            {"units": "m; rad", "long_name": "unloaded configuration Y0"},
        )
    ds.attrs.update(
        {
            "title": "elasticoop trajectory",
            "model": type(model).__name__,
            "convention": model.convention,
            "gravity": float(model.gravity),
            "gravity_units": "m/s^2 along -z",
            "n_bodies": n,
            "status": int(traj.status),
            "status_message": status_message(traj, bodies, conns),
            "event_time": float(traj.event_time),
            "elasticoop_version": __version__,
        }
    )
    for key, value in (attrs or {}).items():
        ds.attrs[key] = value if not isinstance(value, bool) else int(value)
    return ds


def applied_forces(forces, traj) -> np.ndarray:
    """$F(t, Y, \\dot Y)$ of `forces` (as `simulate` takes them) at the saved
    samples of `traj`, `(times, bodies, 6)` (NaN where the state is)."""
    force = check_force(
        forces, traj.y[0], traj.ydot[0], traj.ts, owner="trajectory_to_xarray: "
    )
    values = np.asarray(_applied(force, traj.ts, traj.y, traj.ydot))
    missing = traj.model.n_bodies - values.shape[1]  # 1: no row for the object
    return np.concatenate([np.zeros((len(values), missing, 6)), values], axis=1)


@eqx.filter_jit
def _applied(forces, ts, y, ydot):
    import jax

    return jax.vmap(forces)(ts, y, ydot)


def dataset_to_frame(ds) -> "pandas.DataFrame":
    """The time-dependent variables of a trajectory Dataset as one wide table: a
    column `time [s]`, then one column per variable and label, named
    `<variable>.<body or connection>.<coordinate> [unit]` (`y.beam.z [m]`)."""
    import pandas as pd

    columns = {"time [s]": ds["time"].values}
    for name, var in ds.data_vars.items():
        if var.dims[:1] != ("time",):
            continue
        if var.ndim == 1:
            columns[f"{name} [{var.attrs.get('units', '')}]"] = var.values
            continue
        first, _ = var.dims[1:]
        t_unit, r_unit = _UNITS[name]
        for a, label in enumerate(ds[first].values):
            for c, coord in enumerate(ds["coordinate"].values):
                unit = t_unit if c < 3 else r_unit
                columns[f"{name}.{label}.{coord} [{unit}]"] = var.values[:, a, c]
    return pd.DataFrame(columns)
