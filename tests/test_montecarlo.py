"""Monte Carlo studies: sampling, batched runs against single runs, statistics, the
store, failures and sensitivities."""

import json
import logging
import re

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
import xarray as xr
from helpers import three_body_model, three_body_state

import elasticoop as eo
from elasticoop import montecarlo as mc
from elasticoop.montecarlo import execution

# A batch and a single run differ only by floating-point rounding in the vmapped
# solver (different vectorisation of the same operations).
BATCH_VS_SINGLE_RTOL = 1e-12
# Finite differences of a solve at rtol 1e-12 with relative step 1e-5: truncation
# error ~1e-10, solver noise ~1e-12/1e-5 = 1e-7, both well below the target 1e-5.
FD_STEP = 1e-5
FD_RTOL = 1e-5

BATCH_WIDTH = 4
N_SAMPLES = 24
TS = np.linspace(0.0, 0.3, 7)


def _lift():
    lift = np.zeros((2, 6))
    lift[:, 2] = 3.0
    return lift


def _parameters():
    return [
        mc.Parameter(
            "stiffness", lambda m: m.stiffness, mc.LogNormal(0.0, 0.3), relative=True
        ),
        mc.Parameter(
            "mass",
            lambda m: m.bodies.mass,
            mc.TruncatedNormal((2.0, 0.3, 0.25), 0.05, low=(1.9, 0.2, 0.2)),
        ),
        mc.Parameter(
            "load", None, mc.Uniform(0.5, 1.5), target="forces", relative=True
        ),
    ]


def _outputs():
    return {
        "peak_force": mc.peak_elastic_force(),
        "pose": mc.object_pose(),
        "error": mc.final_pose_error(),
        "deflection": mc.max_deflection(),
    }


def _study(parameters=None, n_samples=N_SAMPLES, key=7, forces=None, **kwargs):
    y0 = three_body_state()
    return mc.Study(
        three_body_model(),
        y0,
        np.zeros_like(y0),
        TS,
        forces=_lift() if forces is None else forces,
        parameters=_parameters() if parameters is None else parameters,
        outputs=_outputs(),
        n_samples=n_samples,
        key=key,
        **kwargs,
    )


# The batch-against-loop comparisons run Tsit5 at rtol 1e-8, on which their bound
# (rounding, BATCH_VS_SINGLE_RTOL) was set: at another solver or tolerance a step
# accepted just below the error threshold in one loop and just above it in the
# other makes the two differ by the tolerance, not by rounding.
COMPARED = eo.SimulationOptions("tsit5", 1e-8, 1e-10)


@pytest.fixture(scope="module")
def study():
    return _study(options=COMPARED)


@pytest.fixture(scope="module")
def results(study):
    return mc.run_study(study, chunk_size=8, batch_width=BATCH_WIDTH, progress=False)


@pytest.fixture(scope="module")
def single_runs(study):
    """A plain Python loop of `simulate` over the same parameter values."""
    values = mc.sample_parameters(study)
    model, y0 = study.inputs.model, study.inputs.y_init

    @eqx.filter_jit
    def run(k, mass, F):
        m = eqx.tree_at(lambda m: (m.stiffness, m.bodies.mass), model, (k, mass))
        traj = eo.simulate(
            m, y0, jnp.zeros_like(y0), TS, forces=F, throw=False, options=COMPARED
        )
        return {name: out(traj) for name, out in study.outputs.items()}

    runs = [
        run(values["stiffness"][s], values["mass"][s], values["load"][s])
        for s in range(study.n_samples)
    ]
    return {k: np.stack([np.asarray(r[k]) for r in runs]) for k in runs[0]}


def test_batch_equals_loop_of_single_runs(results, single_runs):
    assert mc.summary(results)["n_succeeded"] == N_SAMPLES
    for name, expected in single_runs.items():
        np.testing.assert_allclose(
            results[name].values, expected, rtol=BATCH_VS_SINGLE_RTOL, atol=1e-15
        )


def test_statistics_equal_those_of_the_loop(results, single_runs):
    q = (0.1, 0.5, 0.9)
    for name in ("pose", "peak_force"):
        stats = mc.statistics(results, name, quantiles=q)
        x = single_runs[name]
        tol = dict(rtol=BATCH_VS_SINGLE_RTOL, atol=1e-14)
        np.testing.assert_allclose(stats["mean"].values, x.mean(0), **tol)
        np.testing.assert_allclose(stats["std"].values, x.std(0, ddof=1), **tol)
        np.testing.assert_allclose(
            stats["quantiles"].values, np.quantile(x, q, axis=0), **tol
        )
        assert int(stats["n"]) == N_SAMPLES
    # the band over time is labelled with the output times
    np.testing.assert_array_equal(mc.statistics(results, "pose")["time"], TS)


def test_exceedance_probability_with_wilson_interval(results, single_runs):
    threshold = np.median(single_runs["peak_force"], axis=0)
    p = mc.exceedance_probability(results, "peak_force", threshold, confidence=0.9)
    k = (single_runs["peak_force"] > threshold).sum(0)
    np.testing.assert_array_equal(p["probability"].values, k / N_SAMPLES)
    # Wilson interval by hand: z = 1.6449 for 90 %
    z, n = 1.6448536269514722, N_SAMPLES
    ph = k / n
    centre = (ph + z**2 / (2 * n)) / (1 + z**2 / n)
    half = z / (1 + z**2 / n) * np.sqrt(ph * (1 - ph) / n + z**2 / (4 * n**2))
    np.testing.assert_allclose(p["lower"].values, centre - half, rtol=1e-12)
    np.testing.assert_allclose(p["upper"].values, centre + half, rtol=1e-12)
    # zero exceedances: the upper bound is z^2 / (n + z^2), not 0
    lo, hi = mc.wilson_interval(0, 10, 0.95)
    assert lo == 0.0
    np.testing.assert_allclose(hi, 1.959963984540054**2 / (10 + 1.959963984540054**2))


@pytest.mark.slow  # over 10 s
@pytest.mark.parametrize("chunk_size", [BATCH_WIDTH, 10])
def test_chunk_size_does_not_change_results(study, results, chunk_size):
    # BATCH_WIDTH: six chunks of one batch each (the program that
    # test_default_batch_width_follows_the_chunk_size runs again); 10: more
    # samples a chunk than lanes, and the last chunk (4 samples) is padded to the
    # others' length with samples that stop at once
    other = mc.run_study(
        study, chunk_size=chunk_size, batch_width=BATCH_WIDTH, progress=False
    )
    xr.testing.assert_identical(results.drop_attrs(), other.drop_attrs())


@pytest.mark.slow  # over 10 s
def test_default_batch_width_follows_the_chunk_size(study, results):
    # no batch_width: a chunk of BATCH_WIDTH samples on one device is integrated
    # BATCH_WIDTH at a time (not padded to DEFAULT_BATCH_WIDTH), so the values are
    # those of an explicit BATCH_WIDTH bit for bit
    assert len(jax.devices()) == 1
    ds = mc.run_study(study, chunk_size=BATCH_WIDTH, progress=False)
    assert ds.attrs["batch_width"] == BATCH_WIDTH
    xr.testing.assert_identical(results.drop_attrs(), ds.drop_attrs())


def test_studies_differing_in_values_share_one_compilation(study, results):
    """A Study is a pytree: its arrays (model, state, forces, times, key) are traced
    and its structure static, so a study that differs from another only in values
    (a stiffer model, another key, other forces) reuses its compiled batch; so
    does one with more samples in chunks of the same size (random sampling)."""
    model = study.inputs.model
    stiffer = eqx.tree_at(lambda m: m.stiffness, model, 1.5 * model.stiffness)
    other = mc.Study(
        stiffer,
        study.inputs.y_init,
        study.inputs.ydot_init,
        study.ts,
        forces=1.2 * _lift(),
        parameters=study.parameters,
        outputs=study.outputs,
        n_samples=N_SAMPLES + 8,
        key=8,
        options=study.options,
    )
    assert other.sampling == "random"
    traces = eqx.debug.get_num_traces(execution._run_batch)
    assert traces >= 1  # the `results` fixture compiled this structure
    ds = mc.run_study(other, chunk_size=8, batch_width=BATCH_WIDTH, progress=False)
    assert eqx.debug.get_num_traces(execution._run_batch) == traces
    # ... and really simulated the new values
    values = mc.sample_parameters(other)
    for name in ("stiffness", "mass", "load"):
        np.testing.assert_array_equal(ds[name].values, values[name])
    first = ds.isel(sample=slice(N_SAMPLES))
    assert not np.array_equal(first["stiffness"].values, results["stiffness"].values)
    assert not np.any(first["peak_force"].values == results["peak_force"].values)
    assert mc.summary(ds)["n_succeeded"] == N_SAMPLES + 8


def test_axes_are_labelled_in_the_export_vocabulary(study, results):
    """`coordinate`, `connection` and `time` are labelled as in
    `trajectory_to_xarray` (the model's convention: ZXZ angles here)."""
    assert study.inputs.model.convention == "zxz"
    assert list(results["coordinate"].values) == [
        "x",
        "y",
        "z",
        "psi",
        "theta",
        "phi",
    ]
    assert list(results["connection"].values) == ["object-contact1", "object-contact2"]
    np.testing.assert_array_equal(results["time"].values, TS)
    assert study.describe()["solver"] == "tsit5"


def test_sampling_is_reproducible_and_per_sample(study):
    values = mc.sample_parameters(study)
    again = mc.sample_parameters(study, np.array([5, 3]))
    for name in values:
        np.testing.assert_array_equal(again[name], values[name][[5, 3]])
    other_key = mc.sample_parameters(_study(key=8))
    assert not np.array_equal(other_key["stiffness"], values["stiffness"])
    # the drawn values follow their laws' supports and scalings
    assert np.all(values["mass"] >= np.array([1.9, 0.2, 0.2]))
    assert np.all(values["load"][:, :, 2] >= 0.5 * 3.0)
    assert np.all(values["load"][:, :, 2] <= 1.5 * 3.0)
    np.testing.assert_array_equal(values["load"][:, :, :2], 0.0)


def test_latin_hypercube_hits_every_stratum_once():
    n = 50
    uniform = mc.Parameter("stiffness", lambda m: m.stiffness, mc.Uniform(0.0, 1.0))
    lhs = _study([uniform], n_samples=n, sampling="lhs")
    u = mc.sample_parameters(lhs)["stiffness"].reshape(n, -1)
    strata = np.sort(np.floor(u * n).astype(int), axis=0)
    np.testing.assert_array_equal(strata, np.repeat(np.arange(n)[:, None], 12, 1))
    # a normal law through its inverse CDF: strata of equal probability
    normal = mc.Parameter("stiffness", lambda m: m.stiffness, mc.Normal(1.0, 2.0))
    x = mc.sample_parameters(_study([normal], n_samples=n, sampling="lhs"))
    z = (x["stiffness"].reshape(n, -1) - 1.0) / 2.0
    from scipy.stats import norm

    strata = np.sort(np.floor(norm.cdf(z) * n).astype(int), axis=0)
    np.testing.assert_array_equal(strata, np.repeat(np.arange(n)[:, None], 12, 1))


@pytest.mark.parametrize(
    "low, high",
    [(8.0, np.inf), (1.08, np.inf), (2.0, 2.5), (-np.inf, -7.0), (-1.0, 2.0)],
)
def test_truncated_normal_inverse_cdf_in_both_tails(low, high):
    """The inverse CDF against SciPy's `truncnorm` on 2001 quantiles, in the upper
    tail too (there Phi(low) is close to 1: the draws were almost all inf at 8
    standard deviations above the mean)."""
    from scipy import stats

    u = (np.arange(2001) + 0.5) / 2001
    mean, std = 1.0, 0.01
    d = mc.TruncatedNormal(mean, std, low=mean + low * std, high=mean + high * std)
    x = np.asarray(d.ppf(jnp.asarray(u)))
    expected = mean + std * stats.truncnorm(low, high).ppf(u)
    reach = max(abs(b) for b in (low, high, 1.0) if np.isfinite(b))
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-13 * std * reach)
    assert np.all(np.diff(x) > 0)


def test_store_resume_and_loader(study, results, tmp_path):
    store = tmp_path / "study"
    ran = []
    ds = mc.run_study(
        study,
        store,
        chunk_size=8,
        batch_width=BATCH_WIDTH,
        progress=False,
        on_chunk=ran.append,
    )
    assert ran == [0, 1, 2]
    xr.testing.assert_identical(ds.drop_attrs(), results.drop_attrs())
    manifest = json.loads((store / "manifest.json").read_text())
    assert manifest["study"]["key"] == study.key_data.tolist()
    # every chunk opens with plain NumPy
    with np.load(store / "chunk-000001.npz") as chunk:
        np.testing.assert_array_equal(chunk["sample"], np.arange(8, 16))
    # a lost chunk and a half-written one: only the lost chunk is recomputed,
    # the temporary file is never read and is cleaned up
    (store / "chunk-000001.npz").unlink()
    (store / ".chunk-000001.npz.999.tmp").write_bytes(b"PK\x03\x04 half")
    partial = mc.open_study(store)
    assert partial.attrs["complete"] == 0 and partial.sizes["sample"] == 16
    ran.clear()
    ds = mc.run_study(
        study, store, batch_width=BATCH_WIDTH, progress=False, on_chunk=ran.append
    )
    assert ran == [1]
    assert not list(store.glob(".*.tmp"))
    xr.testing.assert_identical(mc.open_study(store), ds)
    xr.testing.assert_identical(ds.drop_attrs(), results.drop_attrs())
    # another study, or other settings, never mix into this store
    with pytest.raises(ValueError, match="holds another study"):
        mc.run_study(_study(key=8), store, batch_width=BATCH_WIDTH, progress=False)
    with pytest.raises(ValueError, match="chunk_size = 4"):
        mc.run_study(study, store, chunk_size=4, batch_width=BATCH_WIDTH)


@pytest.mark.slow
def test_failing_samples_are_counted_and_others_unaffected(results):
    """Some samples start at gimbal lock, some draw a NaN: both are recorded,
    the study goes on, and every other sample is bit-identical."""
    y0 = np.asarray(three_body_state())

    def initial_state(key):
        u = jax.random.uniform(key)
        theta = jnp.where(u < 0.25, 1e-4, np.pi / 2)  # below GIMBAL_TOL: locked
        theta = jnp.where(u > 0.85, jnp.nan, theta)  # an invalid draw
        return jnp.asarray(y0).at[0, 4].set(theta)

    params = _parameters() + [
        mc.Parameter("state", None, mc.Custom(initial_state), target="y_init")
    ]
    ds = mc.run_study(
        _study(params, options=COMPARED),
        chunk_size=8,
        batch_width=BATCH_WIDTH,
        progress=False,
    )
    theta = ds["state"].values[:, 0, 4]
    locked, invalid = theta == 1e-4, np.isnan(theta)
    assert locked.any() and invalid.any() and (~locked & ~invalid).any()
    summary = mc.summary(ds)
    assert summary["failures"] == {
        "INVALID_SAMPLE": int(invalid.sum()),
        "GIMBAL_LOCK": int(locked.sum()),
    }
    assert summary["n_succeeded"] == int((~locked & ~invalid).sum())
    np.testing.assert_array_equal(ds["status"].values[locked], eo.Status.GIMBAL_LOCK)
    assert np.all(np.isnan(ds["peak_force"].values[locked | invalid]))
    ok = ~locked & ~invalid
    for name in ("peak_force", "pose", "stiffness"):
        np.testing.assert_array_equal(ds[name].values[ok], results[name].values[ok])
    stats = mc.statistics(ds, "peak_force")
    assert int(stats["n"]) == ok.sum()
    conservative = mc.exceedance_probability(ds, "peak_force", 0.0, failures="exceed")
    np.testing.assert_array_equal(conservative["probability"], 1.0)


@pytest.mark.slow
def test_draws_no_constructor_accepts_are_invalid_samples():
    """A negative mass or a negative stiffness drawn is not simulated (it ran, and
    counted as a success): `INVALID_SAMPLE`, NaN outputs, the values drawn kept,
    and the other samples as in a study of their values alone."""
    params = [
        mc.Parameter("mass", lambda m: m.bodies.mass, mc.Normal((2.0, 0.3, 0.25), 0.2)),
        mc.Parameter(
            "stiffness", lambda m: m.stiffness, mc.Normal(1.0, 0.6), relative=True
        ),
    ]
    study = _study(params, n_samples=16)
    ds = mc.run_study(study, batch_width=BATCH_WIDTH, progress=False)
    mass, stiffness = ds["mass"].values, ds["stiffness"].values
    bad = np.any(mass <= 0, axis=1) | np.any(stiffness < 0, axis=(1, 2))
    assert bad.any() and (~bad).any()
    status = ds["status"].values
    np.testing.assert_array_equal(status[bad], mc.INVALID_SAMPLE)
    np.testing.assert_array_equal(status[~bad], eo.Status.SUCCESS)
    assert np.all(np.isnan(ds["peak_force"].values[bad]))
    # local sensitivities flag the same samples
    pair = [int(np.flatnonzero(bad)[0]), int(np.flatnonzero(~bad)[0])]
    local = mc.local_sensitivities(study, indices=pair, batch_width=2)
    np.testing.assert_array_equal(local["status"], status[pair])
    # the values drawn are recorded, as `sample_parameters` gives them (to the
    # last bits: another compiled program)
    drawn = mc.sample_parameters(study)
    np.testing.assert_allclose(mass, drawn["mass"], rtol=1e-14)
    np.testing.assert_allclose(stiffness, drawn["stiffness"], rtol=1e-14)
    # a valid sample is what `simulate` gives for its values
    k = int(np.flatnonzero(~bad)[0])
    model = eqx.tree_at(
        lambda m: (m.bodies.mass, m.stiffness),
        three_body_model(),
        (jnp.asarray(mass[k]), jnp.asarray(stiffness[k])),
    )
    y0 = three_body_state()
    traj = eo.simulate(model, y0, jnp.zeros_like(y0), TS, forces=_lift())
    np.testing.assert_allclose(
        ds["peak_force"].values[k], mc.peak_elastic_force()(traj), rtol=1e-12
    )


@pytest.mark.slow
def test_a_lift_drawn_without_duration_is_an_invalid_sample():
    """A drawn pose-tracking force whose lift has no duration is not simulated:
    `INVALID_SAMPLE` (its constructor refuses it), the others run."""
    y0 = np.asarray(three_body_state())
    lift = eo.PoseTracking(
        y_ref=y0[1:],
        feedforward=np.zeros((2, 6)),
        kp=np.full(6, 100.0),
        kd=np.full(6, 1.0),
        height=0.01,
        duration=0.2,
    )
    duration = mc.Parameter(
        "duration", lambda f: f.duration, mc.Uniform(-0.1, 0.3), target="forces"
    )
    ds = mc.run_study(
        _study([duration], n_samples=8, forces=lift, sampling="lhs"),  # 2 below 0
        batch_width=BATCH_WIDTH,
        progress=False,
    )
    drawn = ds["duration"].values
    assert (drawn <= 0).any() and (drawn > 0).any()
    np.testing.assert_array_equal(ds["status"].values[drawn <= 0], mc.INVALID_SAMPLE)
    np.testing.assert_array_equal(ds["status"].values[drawn > 0], eo.Status.SUCCESS)


@pytest.mark.slow
def test_sensitivities_match_finite_differences(caplog):
    params = [
        mc.Parameter(
            "stiffness", lambda m: m.stiffness, mc.LogNormal(0.0, 0.2), relative=True
        ),
        mc.Parameter(
            "mass", lambda m: m.bodies.mass, mc.Normal((2.0, 0.3, 0.25), 0.02)
        ),
    ]
    y0 = three_body_state()

    def study_of(n_samples):
        return mc.Study(
            three_body_model(),
            y0,
            np.zeros_like(y0),
            np.linspace(0.0, 0.2, 5),
            forces=_lift(),
            parameters=params,
            outputs={"error": mc.final_pose_error(), "deflection": mc.max_deflection()},
            n_samples=n_samples,
            key=3,
            options=eo.SimulationOptions(rtol=1e-12, atol=1e-14),
        )

    study = study_of(2)
    sens = mc.local_sensitivities(study, batch_width=2)
    assert sens.sizes["sample"] == 2
    values = mc.sample_parameters(study)

    @jax.jit
    def outputs(k, mass):
        inputs = eqx.tree_at(
            lambda i: (i.model.stiffness, i.model.bodies.mass), study.inputs, (k, mass)
        )
        traj = eo.simulate(
            inputs.model,
            inputs.y_init,
            inputs.ydot_init,
            study.ts,
            forces=inputs.forces,
            rtol=1e-12,
            atol=1e-14,
            throw=False,
        )
        return {name: out(traj) for name, out in study.outputs.items()}

    s = 1
    theta = {k: jnp.asarray(v[s]) for k, v in values.items()}
    for p_name in ("stiffness", "mass"):
        flat = theta[p_name].reshape(-1)
        # every mass, and the six stiffness entries of connection 0
        for j in range(min(flat.shape[0], 6)):
            h = FD_STEP * float(flat[j])
            plus, minus = dict(theta), dict(theta)
            plus[p_name] = flat.at[j].add(h).reshape(theta[p_name].shape)
            minus[p_name] = flat.at[j].add(-h).reshape(theta[p_name].shape)
            up = outputs(plus["stiffness"], plus["mass"])
            down = outputs(minus["stiffness"], minus["mass"])
            for out in ("error", "deflection"):
                fd = (np.asarray(up[out]) - np.asarray(down[out])) / (2 * h)
                jac = sens[mc.jacobian_name(out, p_name)].values[s]
                ad = jac.reshape(*jac.shape[: fd.ndim], -1)[..., j]
                scale = np.max(np.abs(jac))
                np.testing.assert_allclose(ad, fd, rtol=0, atol=FD_RTOL * scale)
    ranking = mc.variance_ranking(sens, "deflection", connection=0)
    np.testing.assert_allclose(float(ranking.sum()), 1.0, rtol=1e-12)
    assert np.all(np.diff(ranking.values) <= 0)
    # The same study with more samples: its first two are the same draws (the
    # same key), whose derivatives come from the program already compiled. (Only
    # this call's records: with the compile log on for the whole run, as
    # `benchmarks/suite_compilation.py` has it, those of the first are kept too.)
    caplog.clear()
    with caplog.at_level(logging.WARNING, logger="jax"), jax.log_compiles(True):
        first = mc.local_sensitivities(study_of(4), indices=[0, 1], batch_width=2)
    compiled = [r.getMessage() for r in caplog.records]
    assert any("Finished XLA compilation" in m for m in compiled)  # (logged)
    assert not [m for m in compiled if "_jacobians" in m]
    xr.testing.assert_identical(first.drop_attrs(), sens.drop_attrs())


def test_variance_ranking_by_hand():
    """y = 3 a + b with Var(a) = 1, Var(b) = 4: shares 9/13 and 4/13."""
    rng = np.random.default_rng(0)
    a, b = rng.normal(0, 1, 400), rng.normal(0, 2, 400)
    ds = xr.Dataset(
        {
            "status": ("sample", np.zeros(400, np.int32)),
            "a": ("sample", a),
            "b": ("sample", b),
            "y": ("sample", 3 * a + b),
            "d_y_d_a": ("sample", np.full(400, 3.0)),
            "d_y_d_b": ("sample", np.ones(400)),
        }
    )
    ranking = mc.variance_ranking(ds, "y")
    assert list(ranking["parameter"].values) == ["a", "b"]
    va, vb = 9 * a.var(ddof=1), b.var(ddof=1)
    np.testing.assert_allclose(ranking.values, [va / (va + vb), vb / (va + vb)])
    np.testing.assert_allclose(
        ranking.attrs["sample_variance"], (3 * a + b).var(ddof=1)
    )


def test_chunk_size_from_memory_budget(study):
    size = mc.chunk_size_for(study, 2**20, batch_width=4)
    assert size % 4 == 0 and 4 <= size <= N_SAMPLES
    # 24 samples are 3 batches of 8 lanes, fewer than MIN_CHUNKS: one batch a chunk
    assert mc.chunk_size_for(study, 2**30, 4, n_devices=2) == 8
    with pytest.raises(ValueError, match="memory_budget"):
        mc.chunk_size_for(study, 10_000, batch_width=64)


def test_a_thousand_samples_are_not_one_chunk():
    """A chunk is what a killed run loses: at most 1/MIN_CHUNKS of the study's
    batches and _MAX_BATCHES_PER_CHUNK batches. Before, 1,000 samples on 128
    lanes were one chunk of 1024, so Ctrl-C kept nothing."""
    width = mc.DEFAULT_BATCH_WIDTH
    thousand = _study(n_samples=1000)
    assert mc.chunk_size_for(thousand, 2**30, width) == width  # 8 chunks
    big = _study(n_samples=10**6)
    assert mc.chunk_size_for(big, 2**30, width) == 16 * width
    assert mc.chunk_size_for(big, 2**30, width, n_devices=2) == 16 * 2 * width


def test_default_batch_width_fills_the_devices_and_fits_the_memory_budget(study):
    # at most DEFAULT_BATCH_WIDTH; fewer when the samples (or one chunk) do not fill
    # every device; halved until one batch of every device fits the budget
    assert mc.default_batch_width(study, 2**30) == N_SAMPLES
    assert mc.default_batch_width(study, 2**30, n_devices=4) == N_SAMPLES // 4
    assert mc.default_batch_width(study, 2**30, n_devices=5) == 5  # ceil(24 / 5)
    assert mc.default_batch_width(study, 2**30, chunk_size=8) == 8
    assert mc.default_batch_width(study, 2**30, n_devices=2, chunk_size=100) == 12
    many = _study(n_samples=2 * mc.DEFAULT_BATCH_WIDTH + 88)
    assert mc.default_batch_width(many, 2**30) == mc.DEFAULT_BATCH_WIDTH
    assert mc.default_batch_width(many, 2**30, n_devices=2) == mc.DEFAULT_BATCH_WIDTH
    # fewer than the default on each of 4 devices: ceil(samples / 4)
    assert mc.default_batch_width(many, 2**30, n_devices=4) == -(-many.n_samples // 4)
    for budget, devices in ((2**20, 1), (2**20, 2), (400_000, 1), (100_000, 1)):
        width = mc.default_batch_width(study, budget, devices)
        start = -(-N_SAMPLES // devices)
        halvings = [start >> k for k in range(start.bit_length())]
        assert width in halvings
        mc.chunk_size_for(study, budget, width, devices)  # fits
        if width < start:  # the width before the last halving does not
            wider = halvings[halvings.index(width) - 1]
            with pytest.raises(ValueError, match="memory_budget"):
                mc.chunk_size_for(study, budget, wider, devices)
    assert mc.default_batch_width(study, 10) == 1


def test_default_batch_width_on_gpus_takes_the_whole_chunk_up_to_its_cap():
    # on a device that is not a CPU a batch is as wide as the samples each device
    # gets, up to ACCELERATOR_BATCH_WIDTH, and as the memory budget allows
    many = _study(n_samples=2 * mc.DEFAULT_BATCH_WIDTH + 88)
    n = many.n_samples
    assert mc.default_batch_width(many, 2**34, platform="gpu") == n
    assert mc.default_batch_width(many, 2**34, 3, platform="gpu") == -(-n // 3)
    assert mc.default_batch_width(many, 2**34, chunk_size=100, platform="gpu") == 100
    huge = _study(n_samples=2 * mc.ACCELERATOR_BATCH_WIDTH + 1)
    assert mc.default_batch_width(huge, 2**40, platform="gpu") == (
        mc.ACCELERATOR_BATCH_WIDTH
    )
    assert mc.default_batch_width(huge, 2**40) == mc.DEFAULT_BATCH_WIDTH  # CPUs
    # a budget of a third of what the whole chunk needs in one batch
    with pytest.raises(ValueError, match="needs about") as info:
        mc.chunk_size_for(many, 1, n)
    budget = int(re.search(r"needs about (\d+)", str(info.value)).group(1)) // 3
    width = mc.default_batch_width(many, budget, platform="gpu")
    assert width in [n >> k for k in range(2, n.bit_length())]
    mc.chunk_size_for(many, budget, width)  # fits, twice as wide does not
    with pytest.raises(ValueError, match="memory_budget"):
        mc.chunk_size_for(many, budget, 2 * width)


class _Device:
    """A device reporting `bytes_limit` (as GPUs do) or no memory figures (CPUs)."""

    def __init__(self, limit):
        self.limit = limit

    def memory_stats(self):
        return None if self.limit is None else {"bytes_limit": self.limit}


def test_memory_budget_from_the_devices():
    """Half of the smallest GPU's memory per device; CPUs (no figure) and small
    devices keep the default budget."""
    gib = 2**30
    assert mc.memory_budget_for([_Device(80 * gib)]) == 40 * gib
    assert mc.memory_budget_for([_Device(80 * gib), _Device(40 * gib)]) == 40 * gib
    assert mc.memory_budget_for([_Device(None)]) == gib
    assert mc.memory_budget_for([_Device(80 * gib), _Device(None)]) == gib
    assert mc.memory_budget_for([_Device(gib)]) == gib  # never below the default
    assert mc.memory_budget_for(jax.devices("cpu")) == gib


def _two_sample_study(outputs):
    return mc.Study(
        three_body_model(),
        three_body_state(),
        np.zeros((3, 6)),
        TS,
        parameters=_parameters()[:1],
        outputs=outputs,
        n_samples=2,
    )


BAD = {
    "where not a leaf": (
        lambda: _study(
            [mc.Parameter("m0", lambda m: m.bodies.mass[0], mc.Uniform(1, 2))]
        ),
        "whole leaf",
    ),
    "shape mismatch": (
        lambda: _study(
            [mc.Parameter("k", lambda m: m.stiffness, mc.Normal(np.ones(5), 1.0))]
        ),
        "leaf's shape",
    ),
    "lhs custom": (
        lambda: _study(
            [mc.Parameter("k", lambda m: m.stiffness, mc.Custom(lambda key: 1.0))],
            sampling="lhs",
        ),
        "no inverse CDF",
    ),
    "negative std": (lambda: mc.Normal(0.0, -1.0), "Normal.std must be >= 0"),
    "uniform bounds": (lambda: mc.Uniform(2.0, 1.0), "high >= low"),
    "duplicate name": (lambda: _study(_parameters()[:1] * 2), "used twice"),
    "bad target": (
        lambda: mc.Parameter("k", None, mc.Uniform(0, 1), target="gravity"),
        "target must be one of",
    ),
    "n_samples": (lambda: _study(n_samples=0), "n_samples must be >= 1"),
    "sampling": (lambda: _study(sampling="halton"), "sampling must be one of"),
    "rtol": (lambda: _study(rtol=-1.0), "Study.rtol must be a positive number"),
    "solver": (lambda: _study(solver="euler"), "Study.solver must be one of"),
    "max_steps": (lambda: _study(max_steps=0), "Study.max_steps must be a positive"),
    "ts": (
        lambda: mc.Study(
            three_body_model(),
            three_body_state(),
            np.zeros((3, 6)),
            [0.0, 0.2, 0.1],
            parameters=_parameters()[:1],
            outputs=_outputs(),
            n_samples=2,
        ),
        r"Study.ts must be strictly increasing, but Study.ts\[1\]",
    ),
    "forces cover ts": (
        lambda: _study(forces=eo.SampledForce([0.0, 0.1], np.zeros((2, 2, 6)))),
        r"Study.ts spans \[0.0, 0.3\] s but the Study.forces",
    ),
    "output axis": (
        lambda: _two_sample_study(
            {"r": mc.Output(lambda traj: traj.y[-1, 0, :3], ("coordinate",))}
        ),
        "axis 0 is named 'coordinate', which has 6 entries in this study, but has "
        "length 3",
    ),
    "same leaf twice": (
        lambda: _study(
            [
                mc.Parameter(
                    "k1", lambda m: m.stiffness, mc.Uniform(1, 2), relative=True
                ),
                mc.Parameter(
                    "k2", lambda m: m.stiffness, mc.Uniform(1, 2), relative=True
                ),
            ]
        ),
        "Parameter 'k2' selects the same leaf of the model as parameter 'k1'",
    ),
    "parameter named like an axis": (
        lambda: mc.Parameter("coordinate", lambda m: m.stiffness, mc.Uniform(1, 2)),
        "Parameter.name 'coordinate' is reserved",
    ),
    "output named like an axis": (
        lambda: _two_sample_study({"body": mc.peak_elastic_force()}),
        "Study.outputs: name 'body' clashes with a reserved",
    ),
    "mask as indices": (
        lambda: mc.sample_parameters(_study(), np.arange(N_SAMPLES) % 2 == 0),
        "indices must be integer sample numbers, got an array of dtype bool",
    ),
    "fractional indices": (
        lambda: mc.sample_parameters(_study(), [2.9]),
        "indices must be integer sample numbers, got an array of dtype float64",
    ),
    "no sensitivities": (
        lambda: mc.local_sensitivities(_study(), indices=[]),
        "indices must name at least one sample",
    ),
    "no devices": (
        lambda: mc.run_study(_study(), devices=[], progress=False),
        "devices must name at least one device",
    ),
    "wilson k > n": (lambda: mc.wilson_interval(5, 3), "0 <= successes <= n"),
    "wilson n = 0": (lambda: mc.wilson_interval(0, 0), "n >= 1"),
}


@pytest.mark.parametrize("case", BAD)
def test_bad_input_is_named(case):
    make, match = BAD[case]
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_queries_of_results_are_named(study, results):
    with pytest.raises(ValueError, match="threshold must not be NaN"):
        mc.exceedance_probability(results, "peak_force", np.nan)
    with pytest.raises(ValueError, match=r"threshold of shape \(4,\) does not"):
        mc.exceedance_probability(results, "peak_force", np.ones(4))
    per_sample = results["peak_force"].shape[1:]
    higher = np.ones((3, *per_sample))  # broadcasts, but to more than one sample's
    with pytest.raises(ValueError, match=r"threshold of shape \(3, "):
        mc.exceedance_probability(results, "peak_force", higher)
    with pytest.raises(ValueError, match="the study has no variable 'nope'"):
        mc.rank_correlations(results, "nope")
    # a NumPy integer is an integer
    np.testing.assert_array_equal(
        mc.run_study(
            study,
            chunk_size=np.int64(8),
            batch_width=BATCH_WIDTH,
            progress=False,
        )["peak_force"],
        results["peak_force"],
    )
