"""Trajectory -> xarray Dataset, netCDF, CSV and JSON summary."""

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pandas as pd
import pytest
import xarray as xr
from helpers import two_body_run

from elasticoop._io.files import write_outputs
from elasticoop._io.summary import format_summary, summarize
from elasticoop._io.xarray import dataset_to_frame, trajectory_to_xarray
from elasticoop._naming import RESULT_SERIES

TS = jnp.linspace(0.0, 0.2, 11)


@pytest.fixture(scope="module")
def traj():
    return two_body_run()[0]


@pytest.fixture(scope="module")
def immobile_traj():
    return two_body_run()[1]


def test_dataset_layout_units_and_parameters(traj):
    ds = traj.to_xarray(body_names=["obj", "grip"])
    assert ds["y"].dims == ("time", "body", "coordinate")
    assert ds["y"].shape == (11, 2, 6)
    assert list(ds["body"].values) == ["obj", "grip"]
    assert list(ds["coordinate"].values) == ["x", "y", "z", "psi", "theta", "phi"]
    assert list(ds["coordinate_unit"].values) == ["m"] * 3 + ["rad"] * 3
    assert ds["time"].attrs["units"] == "s"
    assert ds["y"].attrs["units"].startswith("m (x, y, z); rad")
    assert ds["ydot"].attrs["units"].startswith("m/s (x, y, z); rad/s")
    np.testing.assert_array_equal(ds["y"].values, traj.y)
    np.testing.assert_array_equal(ds["ydot"].values, traj.ydot)
    for name in (
        "kinetic_energy",
        "elastic_energy",
        "gravity_energy",
        "work",
        "dissipated",
        "energy_residual",
    ):
        assert ds[name].dims == ("time",) and ds[name].attrs["units"] == "J"
    np.testing.assert_allclose(ds["kinetic_energy"], traj.kinetic_energy())
    assert ds["elastic_wrench"].dims == ("time", "connection", "coordinate")
    assert list(ds["connection"].values) == ["obj-grip"]
    assert list(ds["body_i"].values) == ["obj"]
    np.testing.assert_allclose(ds["elastic_wrench"], traj.elastic_wrench())
    # Newton's third law: the wrench on body i is dPi/dY of body j
    np.testing.assert_allclose(
        ds["elastic_wrench"].values[:, 0, :3],
        ds["elastic_force"].values[:, 1, :3],
        atol=1e-9,
    )
    np.testing.assert_allclose(ds["stiffness"].values[0, :3], 1e3)
    np.testing.assert_allclose(ds["rest_length"], [0.2])
    np.testing.assert_allclose(ds["mass"], [1.0, 0.2])
    assert ds["mass"].attrs["units"] == "kg"
    assert ds.attrs["model"] == "MobileModel" and ds.attrs["convention"] == "zxz"
    assert ds.attrs["gravity"] == 9.81 and ds.attrs["status"] == 0
    assert "reaction" not in ds


def test_netcdf_csv_and_summary_roundtrip(traj, tmp_path):
    ds = trajectory_to_xarray(traj, attrs={"scenario": "small", "flag": True})
    summary = summarize(traj)
    # the printed breakdown of the energy's change adds up to it (it printed the
    # final kinetic and elastic energies beside the change of the gravity energy)
    energy = summary["energy"]
    parts = [energy[f"{kind}_change"] for kind in ("kinetic", "elastic", "gravity")]
    assert sum(parts) == pytest.approx(energy["total_change"], rel=1e-12)
    assert energy["kinetic_change"] == pytest.approx(
        float(traj.kinetic_energy()[-1] - traj.kinetic_energy()[0]), rel=1e-12
    )
    line = next(x for x in format_summary(summary).splitlines() if "change of" in x)
    assert f"kinetic {energy['kinetic_change']:+.6f}" in line
    paths = write_outputs(ds, summary, tmp_path / "out")
    # the measured-data reader knows the result columns as such (`RESULT_SERIES`)
    series = {v for v in ds.data_vars if ds[v].dims[:1] == ("time",)} - {"y", "ydot"}
    assert series and series <= set(RESULT_SERIES)
    back = xr.open_dataset(paths["netcdf"], engine="h5netcdf")
    np.testing.assert_array_equal(back["y"].values, ds["y"].values)
    np.testing.assert_array_equal(back["time"].values, np.asarray(TS))
    assert back["time"].dtype == np.float64  # not decoded as a timedelta
    assert back.attrs["scenario"] == "small" and back.attrs["flag"] == 1
    assert list(back["body"].values) == ["object", "contact1"]
    back.close()
    frame = pd.read_csv(paths["csv"])
    # time, y and ydot (2 x 12), 6 energies, elastic_force (12), wrench (6)
    assert frame.shape == (11, 1 + 24 + 6 + 12 + 6)
    assert frame.columns[0] == "time [s]"
    np.testing.assert_allclose(frame["y.contact1.z [m]"], traj.y[:, 1, 2])
    np.testing.assert_allclose(frame["ydot.object.theta [rad/s]"], traj.ydot[:, 0, 4])
    np.testing.assert_allclose(frame["work [J]"], traj.work)
    loaded = json.loads(paths["summary"].read_text())
    assert loaded["status"] == 0 and loaded["bodies"] == ["object", "contact1"]
    e = loaded["energy"]
    # the balance closes to the solver's tolerance (rtol 1e-8)
    assert abs(e["total_change"] - e["work_of_forces"] + e["dissipated"]) < 1e-6
    assert e["work_of_forces"] == pytest.approx(float(traj.work[-1]))


def test_reaction_is_exported_when_present(traj):
    reaction = jnp.ones_like(traj.y)
    with_reaction = eqx.tree_at(
        lambda t: t.reaction, traj, reaction, is_leaf=lambda x: x is None
    )
    ds = with_reaction.to_xarray()
    assert ds["reaction"].dims == ("time", "body", "coordinate")
    assert ds["reaction"].attrs["units"].startswith("N (x, y, z); N m")
    np.testing.assert_array_equal(ds["reaction"].values, reaction)
    assert "reaction.object.x [N]" in dataset_to_frame(ds).columns


def test_immobile_dataset_has_K_D_and_y0(immobile_traj):
    ds = immobile_traj.to_xarray()
    assert ds.attrs["model"] == "ImmobileModel"
    assert ds["K"].shape == (12, 12) and ds["D"].dims == ("dof", "dof_col")
    assert ds["dof"].values[6] == "contact1.x"
    np.testing.assert_array_equal(ds["K"].values, immobile_traj.model.K)
    assert "elastic_wrench" not in ds
    s = summarize(immobile_traj)
    assert s["peak_of"] == "contact body" and len(s["peak_force"]) == 1


def test_bad_names_and_batches_are_rejected(traj):
    with pytest.raises(ValueError, match="body_names must be 2 distinct names"):
        traj.to_xarray(body_names=["a"])
    with pytest.raises(ValueError, match="body_names must be 2 distinct names"):
        traj.to_xarray(body_names=["a", "a"])
    with pytest.raises(ValueError, match="body_names must be a list of 2 names, got"):
        traj.to_xarray(body_names="ab")  # (not the bodies 'a' and 'b')
    batch = jax.tree.map(lambda x: jnp.stack([x, x]), traj)
    with pytest.raises(ValueError, match="single trajectory"):
        trajectory_to_xarray(batch)
