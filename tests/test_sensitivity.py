"""Global sensitivity analysis: the designs, and the estimators against known
indices (Ishigami, a linear model, a static deflection in closed form run through
`run_study`), DGSM and its bound, and SALib's own code path."""

import importlib.metadata
import json

import numpy as np
import pytest
import xarray as xr
from helpers import three_body_model, three_body_state
from SALib.analyze import sobol as salib_sobol

from elasticoop import montecarlo as mc
from elasticoop.montecarlo.sampling import design_points

KEY = [0, 7]
A, B = 7.0, 0.1  # Ishigami
# Analytic indices of the Ishigami function (Saltelli et al. 2008, sect. 3.3)
_V1 = 0.5 * (1 + B * np.pi**4 / 5) ** 2
_V2 = A**2 / 8
_V13 = B**2 * np.pi**8 * (1 / 18 - 1 / 50)
_V = _V1 + _V2 + _V13
ISHIGAMI_S1 = np.array([_V1, _V2, 0.0]) / _V
ISHIGAMI_ST = np.array([_V1 + _V13, _V2, _V13]) / _V


def _ishigami(x):
    return (
        np.sin(x[:, 0]) + A * np.sin(x[:, 1]) ** 2 + B * x[:, 2] ** 4 * np.sin(x[:, 0])
    )


def _results(sampling, x, y, n_samples=None):
    """A dataset laid out as `run_study`'s: factors `x`, outputs `y` (name ->
    array with the sample axis first)."""
    n = x.shape[0]
    study = {
        "n_samples": n if n_samples is None else n_samples,
        "key": KEY,
        "sampling": sampling,
        "parameters": [{"name": "x", "shape": [x.shape[1]]}],
        "outputs": {k: [f"{k}_{i}" for i in range(v.ndim - 1)] for k, v in y.items()},
    }
    data = {"x": (("sample", "x_0"), x), "status": (("sample",), np.zeros(n, np.int32))}
    for k, v in y.items():
        data[k] = (("sample", *[f"{k}_{i}" for i in range(v.ndim - 1)]), v)
    return xr.Dataset(
        data, coords={"sample": np.arange(n)}, attrs={"study": json.dumps(study)}
    )


@pytest.fixture(scope="module")
def ishigami():
    u = design_points("saltelli-second-order", KEY, 3, 1024)
    x = -np.pi + 2 * np.pi * u
    return u, x, _results("saltelli-second-order", x, {"y": _ishigami(x)})


def test_ishigami_indices_lie_within_their_intervals(ishigami):
    _, _, results = ishigami
    ind = mc.sobol_indices(results)
    for key, truth in (("S1", ISHIGAMI_S1), ("ST", ISHIGAMI_ST)):
        error = np.abs(ind[f"{key}_y"].values - truth)
        assert np.all(error <= ind[f"{key}_conf_y"].values), (key, error)
        assert np.all(ind[f"{key}_conf_y"].values < 0.1)
    s13 = ind["S2_y"].sel(factor="x[0]", factor_2="x[2]").values
    conf = ind["S2_conf_y"].sel(factor="x[0]", factor_2="x[2]").values
    assert abs(s13 - _V13 / _V) <= conf
    assert list(ind["factor"].values) == ["x[0]", "x[1]", "x[2]"]


def test_estimates_are_salibs_own_element_by_element(ishigami):
    """Many output elements at once give SALib.analyze.sobol's numbers for each."""
    u, x, _ = ishigami
    y = _ishigami(x)
    two = np.stack([y, np.cos(x[:, 1]) * x[:, 0] + x[:, 2]], axis=1)
    results = _results("saltelli-second-order", x, {"y": two})
    ind = mc.sobol_indices(results, bootstrap=200, seed=4)
    problem = {"num_vars": 3, "names": list("abc"), "bounds": [[0, 1]] * 3}
    for j in range(2):
        ref = salib_sobol.analyze(problem, two[:, j], num_resamples=200, seed=5)
        for key in ("S1", "S1_conf", "ST", "ST_conf", "S2", "S2_conf"):
            ours = ind[f"{key}_y"].isel(y_0=j).values
            np.testing.assert_allclose(ours, ref[key], rtol=1e-12, atol=1e-14)
    # what computed them, kept with them
    for name in ("SALib", "scipy"):
        assert ind.attrs[f"{name}_version"] == importlib.metadata.version(name)


def test_linear_model_indices_and_their_convergence():
    """y = a . x with independent uniform factors: S_i = S_Ti = a_i^2 / |a|^2."""
    a = np.array([1.0, 2.0, 0.5, 0.0])
    u = design_points("saltelli", KEY, 4, 512)
    x = 1.0 + u  # U(1, 2)
    results = _results("saltelli", x, {"y": x @ a})
    ind = mc.sobol_indices(results)
    truth = a**2 / np.sum(a**2)
    for key in ("S1", "ST"):
        error = np.abs(ind[f"{key}_y"].values - truth)
        assert np.all(error <= ind[f"{key}_conf_y"].values + 1e-12), (key, error)
    conv = mc.sobol_convergence(results)
    assert list(conv["base_samples"].values) == [8, 16, 32, 64, 128, 256, 512]
    assert list(conv["runs"].values) == [8 * 6 * 2**k for k in range(7)]
    widths = conv["ST_conf_y"].max("factor").values
    assert widths[-1] < widths[0] / 4  # about N^-1/2 or faster
    table = mc.convergence_table(conv)
    assert [r["base_samples"] for r in table] == list(conv["base_samples"].values)
    assert all(r["top_factor"] == "x[1]" for r in table)


def test_morris_effects_of_a_linear_model_are_its_slopes():
    a = np.array([1.0, -2.0, 0.5])
    u = design_points("morris", KEY, 3, 20)
    x = 1.0 + 3.0 * u  # U(1, 4): x moves 3 * du = 3 * (3/4) per grid unit
    results = _results("morris", x, {"y": x @ a})
    eff = mc.morris_effects(results)
    np.testing.assert_allclose(eff["mu_y"].values, a * 3 * 0.75, rtol=1e-10)
    np.testing.assert_allclose(eff["mu_star_y"].values, np.abs(a) * 2.25, rtol=1e-10)
    np.testing.assert_allclose(eff["sigma_y"].values, 0.0, atol=1e-10)


@pytest.mark.parametrize("sampling", ["sobol", "saltelli", "morris"])
def test_designs_keep_their_rows_when_extended(sampling):
    """Row s depends on the key and s only: a larger design starts with the
    smaller one."""
    small = design_points(sampling, KEY, 5, 8)
    large = design_points(sampling, KEY, 5, 16)
    np.testing.assert_array_equal(large[: small.shape[0]], small)
    assert np.all((small > 0) & (small < 1))


G = 9.81
MASS = mc.Uniform(1.5, 2.5)  # the object's mass [kg]
LOG_STD = 0.3  # the z stiffness of grasp 1 is k0 exp(0.3 Z)


def _stiffness(m):
    return m.stiffness


def _masses(m):
    return m.bodies.mass


def _sag(traj):
    return traj.model.bodies.mass[0] * G / traj.model.stiffness[0, 2]


# The static deflection study is run at this chunk size and batch width by both
# tests that run it, and its callables are module functions, so that the same
# number of samples is one compiled program for both.
CHUNK, WIDTH = 192, 64


def _deflection_study(n_base, sampling="saltelli"):
    """The static deflection m g / k of the object on the z spring of grasp 1,
    of mass ~ U(1.5, 2.5) and stiffness ~ k0 LogNormal(0, 0.3) (a closed form of
    the drawn model, so the indices have one too)."""
    y0 = three_body_state()
    spread = np.zeros((2, 6))
    spread[0, 2] = LOG_STD
    mass_low = np.array([MASS.low, 0.3, 0.25])
    mass_high = np.array([MASS.high, 0.3, 0.25])
    params = [
        mc.Parameter(
            "stiffness",
            _stiffness,
            mc.LogNormal(np.zeros((2, 6)), spread),
            relative=True,
        ),
        mc.Parameter("mass", _masses, mc.Uniform(mass_low, mass_high)),
    ]
    outputs = {"sag": mc.Output(_sag), "deflection": mc.max_deflection()}
    return mc.Study(
        three_body_model(),
        y0,
        np.zeros_like(y0),
        np.linspace(0.0, 0.01, 2),
        parameters=params,
        outputs=outputs,
        n_samples=n_base * (2 + 2),
        sampling=sampling,
        key=11,
    )


def _deflection_truth():
    """S_m, S_k and the totals of m g / k: E[1/k^j] = k0^-j exp(j^2 s^2 / 2)."""
    k0 = 1000.0
    e1, e2 = np.exp(LOG_STD**2 / 2) / k0, np.exp(2 * LOG_STD**2) / k0**2
    m1 = (MASS.low + MASS.high) / 2
    var_m = (MASS.high - MASS.low) ** 2 / 12
    m2 = var_m + m1**2
    var = G**2 * (m2 * e2 - m1**2 * e1**2)
    s_m = G**2 * var_m * e1**2 / var
    s_k = G**2 * m1**2 * (e2 - e1**2) / var
    return np.array([s_k, s_m]), np.array([1 - s_m, 1 - s_k])


@pytest.mark.slow  # ~90 s on 2 shared cores: compiles a study and its derivatives
def test_static_deflection_indices_through_run_study_and_dgsm_bound():
    study = _deflection_study(256)
    assert study.n_samples == 256 * 4  # two varying factors: D + 2 = 4 rows
    results = mc.run_study(study, chunk_size=CHUNK, batch_width=WIDTH, progress=False)
    ind = mc.sobol_indices(results, "sag")
    assert list(ind["factor"].values) == ["stiffness[0, 2]", "mass[0]"]
    s1, st = _deflection_truth()
    for key, truth in (("S1", s1), ("ST", st)):
        error = np.abs(ind[f"{key}_sag"].values - truth)
        assert np.all(error <= ind[f"{key}_conf_sag"].values), (key, error)
    # exact derivatives at 16 points of the design; the bound on each total index
    rows = np.arange(16) * 4
    measures = mc.dgsm(study, rows, ["sag"], bootstrap=200)
    values = mc.sample_parameters(study, rows)
    m, k = values["mass"][:, 0], values["stiffness"][:, 0, 2]
    # nu of log k: E[(d y / d log k)^2] = E[y^2]; nu of m: E[(g / k)^2]
    np.testing.assert_allclose(
        measures["nu_sag"].values, [np.mean((m * G / k) ** 2), np.mean((G / k) ** 2)]
    )
    np.testing.assert_allclose(
        measures["poincare"].values,
        [LOG_STD**2, (MASS.high - MASS.low) ** 2 / np.pi**2],
    )
    check = mc.check_dgsm_bounds(ind, measures)
    assert np.all(check["bound_holds_sag"].values == 1.0)
    assert np.all(measures["dgsm_bound_sag"].values >= st - 0.02)


def test_designs_refuse_sample_counts_they_cannot_have():
    with pytest.raises(ValueError, match=r"N x 4 rows .* power of two.*n_samples = 32"):
        _deflection_study(9)
    with pytest.raises(ValueError, match="Sobol' indices need the Saltelli design"):
        mc.sobol_indices(_results("lhs", np.ones((4, 1)), {"y": np.ones(4)}))
    # a sensitivity design names its own argument, not the n_samples it makes
    nominal = _deflection_study(8)
    with pytest.raises(ValueError, match=r"base_samples = 10: .* e\.g\. 8 or 16"):
        mc.sensitivity_study(nominal, "sobol", base_samples=10)
    with pytest.raises(ValueError, match="base_samples must be a positive integer"):
        mc.sensitivity_study(nominal, "dgsm", base_samples=0)
    assert mc.sensitivity_study(nominal, "morris", base_samples=10).n_samples == 30


@pytest.mark.slow  # two runs of the deflection study's program (the test above's)
def test_a_stored_study_extends_with_more_samples_keeping_its_chunks(tmp_path):
    # the larger study is that of the test above (the same program)
    store = tmp_path / "store"
    small = mc.run_study(
        _deflection_study(128),
        store,
        chunk_size=CHUNK,
        batch_width=WIDTH,
        progress=False,
    )
    assert small.sizes["sample"] == 512  # chunks 0, 1 full; chunk 2 holds 128
    done: list[int] = []
    large = mc.run_study(
        _deflection_study(256),
        store,
        batch_width=WIDTH,
        progress=False,
        on_chunk=done.append,
    )
    assert done == [2, 3, 4, 5]  # the short last chunk again, then the new ones
    assert large.sizes["sample"] == 1024
    for name in ("stiffness", "mass", "sag", "status"):
        np.testing.assert_array_equal(large[name].values[:512], small[name].values)
    ind = mc.sobol_indices(large, "sag")
    assert ind.attrs["base_samples"] == 256
    with pytest.raises(mc.StoreError, match="holds another study"):
        mc.run_study(_deflection_study(128), store, batch_width=WIDTH, progress=False)


def test_plots_of_the_indices(ishigami):
    """Bars, a heat map over time, convergence and Morris plots draw what they are
    given (one panel per output element)."""
    from elasticoop import (
        plot_morris,
        plot_sobol_convergence,
        plot_sobol_heatmap,
        plot_sobol_indices,
    )

    u, x, _ = ishigami
    y = _ishigami(x)
    over_time = np.stack([y * t for t in (0.0, 0.5, 1.0)], axis=1)  # time 0: constant
    results = _results("saltelli-second-order", x, {"y": y, "series": over_time})
    results = results.rename({"series_0": "time"}).assign_coords(time=[0.0, 0.5, 1.0])
    ind = mc.sobol_indices(results, bootstrap=50)
    assert np.all(np.isnan(ind["ST_series"].isel(time=0).values))  # no variance
    np.testing.assert_allclose(
        ind["ST_series"].isel(time=2).values, ind["ST_y"].values, rtol=1e-12
    )
    assert len(plot_sobol_indices(ind, "y").axes) == 1
    assert plot_sobol_heatmap(ind, "series").axes[0].get_xlabel() == "time [s]"
    # an element without variance at any time is left out and named
    series = results["series"].expand_dims(part=["moves", "still"], axis=2).copy()
    series[:, :, 1] = 1.0
    two = results.assign(series=series)
    maps = plot_sobol_heatmap(mc.sobol_indices(two, "series", bootstrap=50), "series")
    assert [ax.get_title() for ax in maps.axes[:-1]] == ["moves"]  # (and the bar)
    assert "not shown: still" in maps._suptitle.get_text()
    conv = mc.sobol_convergence(results, "y", bootstrap=50)
    assert len(plot_sobol_convergence(conv, "y").axes[0].lines) == 3
    m = design_points("morris", KEY, 3, 10)
    eff = mc.morris_effects(_results("morris", m, {"y": m @ [1.0, 2.0, 3.0]}))
    assert plot_morris(eff, "y").axes[0].get_xlabel() == "$\\mu^*$"
