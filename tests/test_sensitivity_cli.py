"""`elasticoop montecarlo sensitivity` as a user runs it: the `[sensitivity]`
table's problems named; the shipped study's table run at small size, analysed
again from its store, and extended with more base points; Morris screening and
DGSM run from a study file and analysed again, against a hanging box whose
outputs have a closed form."""

import importlib.metadata
import json

import numpy as np
import pytest
import xarray as xr

from elasticoop import montecarlo as mc
from elasticoop._cli import main
from elasticoop._examples import example_studies
from elasticoop.montecarlo.sampling import MORRIS_LEVELS

SHIPPED = example_studies()["beam_lift"]


def _small_study(tmp_path, sensitivity=None):
    """The shipped study on a 0.3 s span with 7 output times (its scenario named as
    a shipped example), its `[sensitivity]` table replaced by `sensitivity`."""
    text = SHIPPED.read_text(encoding="utf-8")
    text = text.replace('scenario = "beam_lift.toml"', 'scenario = "beam_lift"')
    text = text.replace("[time]\nsamples = 61", "[time]\nstop = 0.3\nsamples = 7")
    if sensitivity is not None:
        text = text[: text.index("[sensitivity]")] + sensitivity
    path = tmp_path / "small.study.toml"
    path.write_text(text, encoding="utf-8")
    return path


@pytest.mark.parametrize(
    "table, message",
    [
        ("[sensitivity]\nsamples = 100\n", "samples = 100: the sobol design takes a"),
        ('[sensitivity]\noutputs = ["force"]\n', "no output named 'force'"),
        ('[sensitivity]\nmethod = "fast"\n', "method"),
        ('[sensitivity]\nmethod = "morris"\nsecond_order = true\n', "needs method"),
    ],
)
def test_a_bad_sensitivity_table_is_named(tmp_path, capsys, table, message):
    study = _small_study(tmp_path, table)
    code = main(["montecarlo", "sensitivity", str(study), "-o", str(tmp_path / "s")])
    err = capsys.readouterr().err
    assert code == 2 and "[sensitivity]" in err and message in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "samples, message",
    [
        ("3", "--samples 3: the sobol design takes a power of two of base points"),
        ("1", "--samples 1: input should be greater than or equal to 2 (got 1)"),
    ],
)
def test_samples_that_do_not_fit_the_design_are_named(
    tmp_path, capsys, samples, message
):
    # Before: a traceback ("This is a bug in elasticoop"), exit code 1.
    study = _small_study(tmp_path)
    argv = ["montecarlo", "sensitivity", str(study), "-o", str(tmp_path / "s")]
    assert main([*argv, "--samples", samples]) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err, err
    assert not (tmp_path / "s").exists()


def test_a_store_of_another_design_is_refused_with_the_way_out(tmp_path, capsys):
    assert main(["montecarlo", "sensitivity", str(tmp_path)]) == 2
    assert "not a study store" in capsys.readouterr().err


@pytest.mark.slow  # ~2 min on 2 shared cores: compiles the beam lift, derivatives
def test_sensitivity_runs_analyses_again_and_extends(tmp_path, capsys):
    study = _small_study(tmp_path)
    store = tmp_path / "sobol"
    argv = ["montecarlo", "sensitivity", str(study), "-o", str(store)]
    assert main([*argv, "--samples", "2"]) == 0, capsys.readouterr().err
    out, err = capsys.readouterr()
    assert "Monte Carlo" not in err  # no progress bar where stderr is no terminal
    assert "Sobol' indices from 2 base points (54 runs)" in out
    assert "stiffness[beam-left, x]" in out and "DGSM bound" in out
    folder = store / "sensitivity"
    written = {p.name for p in folder.iterdir()}
    assert {"indices.nc", "indices.json", "heatmap_pose.png"} <= written
    assert {"sobol_peak_force.png", "convergence_peak_force.png"} <= written
    # the JSON holds the indices the Python API gives on the store
    report = json.loads((folder / "indices.json").read_text())
    ds = mc.open_study(store)
    ind = mc.sobol_indices(ds, ["peak_force"], bootstrap=1000)
    stored = report["indices"]["variables"]["ST_peak_force"]["data"]
    np.testing.assert_allclose(np.asarray(stored, float), ind["ST_peak_force"].values)
    assert report["indices"]["coords"]["factor"][0] == "stiffness[beam-left, x]"
    # the store alone, analysed again
    assert main(["montecarlo", "sensitivity", str(store), "-q"]) == 0
    # more base points: the stored samples are kept, the new ones run (without
    # the derivatives this time: the table is not part of the stored study)
    study.write_text(study.read_text().replace("dgsm_samples = 16", "dgsm_samples = 0"))
    assert main([*argv, "--samples", "4", "-q"]) == 0, capsys.readouterr().err
    larger = mc.open_study(store)
    assert larger.sizes["sample"] == 4 * 27
    for name in ("peak_force", "stiffness", "status"):
        np.testing.assert_array_equal(larger[name].values[:54], ds[name].values)


# A box of mass m hangs 0.1 m below one hand through an elastic grasp; the hand
# holds its pose (no lift) and every sample starts at rest in its own closed loop,
# so nothing moves: the grasp carries the weight, its peak force is m g whatever
# the grasp's stiffness and damping, and its deflection is m g / k_z. The damping
# enters neither output.
HANGING_BOX = """\
name = "box held by one hand"
[model]
kind = "mobile"
convention = "rpy"
gravity = 9.81

[[bodies]]
name = "box"
mass = 1.0
inertia = [1.0e-3, 1.0e-3, 1.0e-3]

[[bodies]]
name = "hand"
mass = 0.3
inertia = [1.0e-3, 1.0e-3, 1.0e-3]

[[connections]]
bodies = ["box", "hand"]
stiffness = [1.0e4, 1.0e4, 1.0e4, 20.0, 20.0, 20.0]
damping = [30.0, 30.0, 30.0, 0.2, 0.2, 0.2]

[initial]
from = "equilibrium"

[initial.box]
position = [0.0, 0.0, 0.9]
angles = { degrees = [0.0, 0.0, 0.0] }

[initial.hand]
position = [0.0, 0.0, 1.0]
angles = { degrees = [0.0, 0.0, 0.0] }

[forces.pose_tracking]
lift_height = 0.0
lift_time = 1.0
kp = [4.0e3, 4.0e3, 4.0e3, 20.0, 20.0, 20.0]
kd = [80.0, 80.0, 80.0, 0.5, 0.5, 0.5]
feedforward = "hold"

[time]
stop = 0.05
samples = 3
"""
G = 9.81
MASS_LOW, MASS_HIGH = 0.8, 1.2  # the box's mass: 1 kg +- 0.2 kg, uniform
BOX_STUDY = """\
scenario = "box.toml"

[sampling]
samples = 4
seed = 3

[[parameters]]
quantity = "mass"
bodies = ["box"]
distribution = "uniform"
absolute_spread = 0.2

[[parameters]]
quantity = "stiffness"
axes = ["z"]
distribution = "lognormal"
relative_spread = 0.2

[[parameters]]
quantity = "damping"
axes = ["z"]
distribution = "uniform"
relative_spread = 0.3

[[outputs]]
name = "peak_force"
quantity = "peak_elastic_force"

[[outputs]]
name = "deflection"
quantity = "max_deflection"

[sensitivity]
method = "{method}"
samples = {samples}
bootstrap = 100
"""
FACTORS = ["mass[box]", "stiffness[box-hand, z]", "damping[box-hand, z]"]


def _box_study(tmp_path, method, samples):
    (tmp_path / "box.toml").write_text(HANGING_BOX, encoding="utf-8")
    path = tmp_path / "box.study.toml"
    text = BOX_STUDY.format(method=method, samples=samples)
    path.write_text(text, encoding="utf-8")
    return path


def _check_closed_form(store):
    """Every run of the store hangs at rest: peak force m g, deflection m g / k;
    the store says which SALib and SciPy drew its design, and that every sample
    started at rest."""
    ds = mc.open_study(store)
    assert (ds["status"].values == 0).all()
    m, k = ds["mass"].values[:, 0], ds["stiffness"].values[:, 0, 2]
    np.testing.assert_allclose(ds["peak_force"].values[:, 0], m * G, rtol=1e-8)
    np.testing.assert_allclose(ds["deflection"].values[:, 0], m * G / k, rtol=1e-8)
    manifest = json.loads((store / "manifest.json").read_text())
    assert manifest["study"]["initial"] == "equilibrium"
    for name in ("SALib", "scipy", "jax", "diffrax", "elasticoop"):
        assert manifest["versions"][name] == importlib.metadata.version(name)
    return ds


@pytest.mark.slow  # ~40 s on 2 shared cores: compiles the box's study
def test_morris_screening_from_a_study_file_and_again_from_its_store(tmp_path, capsys):
    study = _box_study(tmp_path, "morris", 4)
    store = tmp_path / "morris"
    code = main(["montecarlo", "sensitivity", str(study), "-o", str(store)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "Morris elementary effects, 4 trajectories (16 runs)" in out
    ds = _check_closed_form(store)
    assert ds.sizes["sample"] == 4 * (3 + 1)
    folder = store / "sensitivity"
    effects = xr.load_dataset(folder / "morris.nc", engine="h5netcdf")
    assert list(effects["factor"].values) == FACTORS
    # peak force = m g: the mass moves it by g (high - low) per unit of its CDF,
    # by the same effect on every trajectory (sigma 0); Morris's step of
    # L / (2 (L - 1)) grid units moves the CDF by 1/2 (levels at (l + 1/2) / L)
    mu_star = effects["mu_star_peak_force"].values[:, 0]
    step = MORRIS_LEVELS / (2 * (MORRIS_LEVELS - 1))
    np.testing.assert_allclose(mu_star[0], G * (MASS_HIGH - MASS_LOW) / 2 / step)
    assert effects["sigma_peak_force"].values[0, 0] < 1e-6 * mu_star[0]
    assert np.all(mu_star[1:] < 1e-6 * mu_star[0])  # stiffness, damping: none
    # deflection = m g / k: mass and stiffness act, the damping does not
    mu_star = effects["mu_star_deflection"].values[:, 0]
    assert np.all(mu_star[:2] > 0.1 * mu_star.max())
    assert mu_star[2] < 1e-6 * mu_star.max()
    report = json.loads((folder / "morris.json").read_text())
    assert report["morris"]["attrs"]["SALib_version"] == importlib.metadata.version(
        "SALib"
    )
    assert {"morris_peak_force.png", "morris_deflection.png"} <= {
        p.name for p in folder.iterdir()
    }
    # the store alone, analysed again: the same effects
    (folder / "morris.nc").unlink()
    assert main(["montecarlo", "sensitivity", str(store), "-q"]) == 0
    again = xr.load_dataset(folder / "morris.nc", engine="h5netcdf")
    xr.testing.assert_identical(again, effects)


@pytest.mark.slow  # compiles the derivatives (and the box's study when run alone)
def test_dgsm_from_a_study_file_bounds_what_drives_and_zeroes_what_does_not(
    tmp_path, capsys
):
    # 16 points: as many runs as the Morris screening's above, so that this study
    # runs the programs that one compiled (the command line keeps them on disk)
    study = _box_study(tmp_path, "dgsm", 16)
    store = tmp_path / "dgsm"
    code = main(["montecarlo", "sensitivity", str(study), "-o", str(store)])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "derivative-based measures at 16 points" in out
    ds = _check_closed_form(store)
    assert ds.sizes["sample"] == 16
    folder = store / "sensitivity"
    measures = xr.load_dataset(folder / "dgsm.nc", engine="h5netcdf")
    assert list(measures["factor"].values) == FACTORS
    m, k = ds["mass"].values[:, 0], ds["stiffness"].values[:, 0, 2]
    c_mass = (MASS_HIGH - MASS_LOW) ** 2 / np.pi**2  # Poincare constant of U(a, b)
    np.testing.assert_allclose(measures["poincare"].values[:2], [c_mass, 0.2**2])
    # peak force = m g: nu of the mass is g^2, so its bound is C / Var(m), above
    # its total index (1); stiffness and damping: no derivative, no bound
    nu = measures["nu_peak_force"].values[:, 0]
    np.testing.assert_allclose(nu[0], G**2, rtol=1e-8)
    bound = measures["dgsm_bound_peak_force"].values[:, 0]
    np.testing.assert_allclose(bound[0], c_mass / np.var(m, ddof=1), rtol=1e-8)
    assert bound[0] >= 1.0
    assert np.all(bound[1:] < 1e-12)
    # deflection = m g / k: nu of m is E[(g / k)^2], of log k E[(m g / k)^2]
    nu = measures["nu_deflection"].values[:, 0]
    np.testing.assert_allclose(
        nu[:2], [np.mean((G / k) ** 2), np.mean((m * G / k) ** 2)], rtol=1e-6
    )
    assert measures["dgsm_bound_deflection"].values[2, 0] < 1e-12
    report = json.loads((folder / "dgsm.json").read_text())
    assert report["dgsm"]["attrs"]["scipy_version"] == importlib.metadata.version(
        "scipy"
    )
    # the store alone, analysed again (the derivatives from the recorded file)
    (folder / "dgsm.nc").unlink()
    assert main(["montecarlo", "sensitivity", str(store), "-q"]) == 0
    again = xr.load_dataset(folder / "dgsm.nc", engine="h5netcdf")
    xr.testing.assert_allclose(again, measures, rtol=1e-12)
