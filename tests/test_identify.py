"""Parameter identification: recovery from synthetic data, the equation-error start,
calibrated standard errors, identifiability flags, bad input and failed steps."""

import importlib

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from helpers import three_body_model

import elasticoop as eo
from elasticoop._identify import (
    Experiment,
    equation_error,
    identify,
    optimisers,
    residuals,
    savitzky_golay,
)

# Noise-free data and a 2x-off start: the fit must land on the truth to this
# relative accuracy (the simulator runs at rtol 1e-10, far below it).
RECOVERY_RTOL = 1e-6
# Equation error with exact derivatives is one linear least-squares solve.
EQUATION_ERROR_RTOL = 1e-4
# Spread of repeated estimates vs reported standard errors (issue: factor 1.5).
CALIBRATION_FACTOR = 1.5

STIFF_DAMP = lambda m: (m.stiffness, m.damping)  # noqa: E731
STIFFNESS = lambda m: m.stiffness  # noqa: E731


def _lift(model):
    """Contact forces holding the assembly's weight (grasps share it equally)."""
    F = np.zeros((model.n_manipulators, 6))
    F[:, 2] = float(jnp.sum(model.bodies.mass)) * model.gravity / model.n_manipulators
    return F


def _experiments(
    model, y0, ts, seeds, scale=(0.05, 0.3), noise=None, sigma=None, options=None
):
    """Motions from random initial rates; optionally with Gaussian noise on y."""
    out = []
    forces = _lift(model)
    for seed in seeds:
        rng = np.random.default_rng(seed)
        rates = _rates(model, rng, scale)
        traj = eo.simulate(model, y0, rates, ts, forces=forces, options=options)
        y = np.asarray(traj.y)
        if noise is not None:
            y = y + noise * rng.normal(size=y.shape)
        out.append((traj, Experiment(ts, y, y0, rates, forces=forces, sigma=sigma)))
    return out


def _rates(model, rng, scale=(0.05, 0.3)):
    """Random initial rates, `scale` for the translations and for the angles."""
    return rng.normal(size=(model.n_bodies, 6)) * np.repeat(scale, 3)


@jax.jit
def _accelerations(model, y, ydot, applied):
    """The model's accelerations at the samples `y`, `ydot` under `applied`."""
    return jax.vmap(lambda q, v: eo.accelerations(model, q, v, applied)[0])(y, ydot)


def _exact_derivatives(model, traj, forces):
    applied = eo._forces.pad_to_bodies(jnp.asarray(forces), model.n_bodies)
    return np.asarray(traj.ydot), np.asarray(
        _accelerations(model, traj.y, traj.ydot, applied)
    )


def _flat(model, where):
    return np.concatenate([np.ravel(x) for x in jax.tree.leaves(where(model))])


# --- a small two-body problem: 6 stiffness parameters of one connection ----------

UP = (0.0, np.pi / 2, 0.0)


def _two_body():
    bodies = [eo.RigidBody(1.0, (0.02, 0.03, 0.04)), eo.RigidBody(0.3, (2e-3,) * 3)]
    conn = eo.Connection(
        0,
        1,
        stiffness=(400.0, 500.0, 600.0, 4.0, 5.0, 6.0),
        damping=(0.5,) * 3 + (0.005,) * 3,
    )
    y0 = jnp.array([[0.0, 0.0, 1.0, *UP], [0.4, 0.0, 1.0, *UP]])
    return eo.MobileModel(bodies, [conn]).with_unloaded_state(y0), y0


TS_SMALL = jnp.linspace(0.0, 0.25, 51)
TS_RECOVERY = jnp.linspace(0.0, 0.3, 121)


@pytest.fixture(scope="module")
def two_body_runs():
    model, y0 = _two_body()
    # The data made with the solver that `identify` fits with by default (Tsit5,
    # rtol 1e-8, atol 1e-10): the noise-free recovery's loss bound (1e-12 of the
    # start's) is the floor of a fit whose data and model share one solver; data
    # from simulate's own default (Dopri8, rtol 1e-9) differ from the fit's model
    # by the two solvers' error, a floor of its own.
    tsit5 = eo.SimulationOptions("tsit5", 1e-8, 1e-10)
    return model, _experiments(model, y0, TS_RECOVERY, seeds=(1, 2), options=tsit5)


# A fit compiles the Levenberg-Marquardt step with forward-mode derivatives through
# simulate (about half a minute); the fast tests cover the data, the equation-error
# estimate and the checks of the arguments.
@pytest.mark.slow
def test_noise_free_recovery_from_2x_off(two_body_runs):
    model, runs = two_body_runs
    start = eqx.tree_at(STIFF_DAMP, model, (2 * model.stiffness, 2 * model.damping))
    result = identify(start, [e for _, e in runs], STIFF_DAMP, window=7, progress=False)
    assert result.converged, result.reason
    truth = _flat(model, STIFF_DAMP)
    np.testing.assert_allclose(result.estimate, truth, rtol=RECOVERY_RTOL)
    np.testing.assert_allclose(
        _flat(result.model, STIFF_DAMP), truth, rtol=RECOVERY_RTOL
    )
    assert result.loss_history[-1] < 1e-12 * result.loss_history[0]
    assert result.n_simulations >= 2 * result.n_iterations
    stderr = jax.tree.leaves(result.stderr)
    assert [s.shape for s in stderr] == [(1, 6), (1, 6)]
    assert "stiffness[0-1].x" in result.report()
    # noise-free data: the equation-error start simulates closer than 2x off
    assert any("started from the equation-error start" in n for n in result.notes)


@pytest.mark.slow  # a fit of its own (one experiment, stiffness only)
def test_start_is_the_candidate_that_fits_better():
    """With noisy samples the equation-error estimate is off by far more than the
    noise allows; starting from the true values, `identify` must keep them."""
    model, y0 = _two_body()
    ((traj, clean),) = _experiments(model, y0, TS_SMALL, seeds=(7,))
    rng = np.random.default_rng(99)
    y = np.asarray(traj.y) + 1e-5 * rng.normal(size=traj.y.shape)
    e = Experiment(TS_SMALL, y, y0, clean.ydot_init, forces=_lift(model), sigma=1e-5)
    linear = equation_error(model, e, STIFFNESS, window=7)
    result = identify(model, e, STIFFNESS, window=7, max_iterations=1, progress=False)
    # off by far more than the noise allows: tens of the fit's standard errors
    off = np.abs(_flat(linear, STIFFNESS) - _flat(model, STIFFNESS))
    assert np.max(off / np.ravel(result.stderr)) > 10
    np.testing.assert_array_equal(result.initial, _flat(model, STIFFNESS))
    assert any("started from the model's values" in n for n in result.notes)


@pytest.mark.slow  # the motions of the recovery above (shared)
def test_equation_error_exact_derivatives(two_body_runs):
    """With the measured accelerations the model's own (exact derivatives), the
    equation error is zero at the truth: the linear least-squares estimate lands
    on it from a start 2x off in stiffness and 0.3x in damping."""
    model, runs = two_body_runs
    forces = _lift(model)
    exps = []
    for traj, e in runs:
        ydot, yddot = _exact_derivatives(model, traj, forces)
        exps.append(
            Experiment(
                traj.ts, traj.y, e.y_init, e.ydot_init, forces, ydot=ydot, yddot=yddot
            )
        )
    start = eqx.tree_at(STIFF_DAMP, model, (2 * model.stiffness, 0.3 * model.damping))
    fitted = equation_error(start, exps, STIFF_DAMP)
    np.testing.assert_allclose(
        _flat(fitted, STIFF_DAMP), _flat(model, STIFF_DAMP), rtol=EQUATION_ERROR_RTOL
    )


def test_savitzky_golay_matches_scipy():
    signal = pytest.importorskip("scipy.signal")
    ts = np.linspace(0.0, 1.0, 201)
    rng = np.random.default_rng(0)
    x = np.stack([np.sin(7 * ts), ts**3], axis=1) + 1e-3 * rng.normal(size=(201, 2))
    ours = savitzky_golay(x, ts, window=15, polyorder=4)
    for d, est in enumerate(ours):
        ref = signal.savgol_filter(
            x, 15, 4, deriv=d, delta=ts[1] - ts[0], axis=0, mode="interp"
        )
        np.testing.assert_allclose(est, ref, rtol=1e-9, atol=1e-9 * np.abs(ref).max())
    # exact on a polynomial of degree <= polyorder
    p = 1 + 2 * ts - ts**2 + 0.5 * ts**4
    _, d1, d2 = savitzky_golay(p, ts, window=9, polyorder=4)
    np.testing.assert_allclose(d1, 2 - 2 * ts + 2 * ts**3, atol=1e-9)
    np.testing.assert_allclose(d2, -2 + 6 * ts**2, atol=1e-7)


def _fit_traces() -> tuple[int, ...]:
    """How often a fit's compiled programs have been traced: its simulations
    without and with sensitivities and the trust region's update."""
    return tuple(
        eqx.debug.get_num_traces(f)
        for f in (residuals.evaluate, residuals._sensitivities, optimisers._lm_update)
    )


@pytest.mark.slow
def test_standard_errors_are_calibrated():
    """One experiment, fresh seeded noise in each of `repeats` data sets: the
    spread of the estimates must match the reported standard errors. The fits
    after the first (new data, same problem) must not retrace."""
    model, y0 = _two_body()
    noise, repeats = 1e-5, 20
    ((traj, clean),) = _experiments(model, y0, TS_SMALL, seeds=(7,))
    estimates, stderrs = [], []
    for k in range(repeats):
        rng = np.random.default_rng(1000 + k)
        y = np.asarray(traj.y) + noise * rng.normal(size=traj.y.shape)
        e = Experiment(
            TS_SMALL, y, y0, clean.ydot_init, forces=_lift(model), sigma=noise
        )
        result = identify(model, e, STIFFNESS, init="model", progress=False)
        assert result.converged, result.reason
        estimates.append(result.estimate)
        stderrs.append(result.uncertainty.stderr)
        if k == 0:
            traces = _fit_traces()
    # the fits after the first (new data, same problem) reused its compilation
    assert min(traces) >= 1
    assert _fit_traces() == traces
    spread = np.std(np.asarray(estimates), axis=0, ddof=1)
    reported = np.mean(np.asarray(stderrs), axis=0)
    ratio = spread / reported
    assert np.all(ratio < CALIBRATION_FACTOR), ratio
    assert np.all(ratio > 1 / CALIBRATION_FACTOR), ratio
    # and the estimates scatter about the truth (bias << spread)
    bias = np.mean(np.asarray(estimates), axis=0) - _flat(model, STIFFNESS)
    assert np.all(np.abs(bias) < 3 * reported / np.sqrt(repeats)), bias / reported


# Zero contact forces, an array like `_lift`'s: the simulations of the data of the
# one-experiment fits share their compiled program.
FREE_FALL = np.zeros((1, 6))


@pytest.mark.slow  # a fit like the other one-experiment fits above (shared)
def test_unexcited_parameters_are_flagged():
    model, y0 = _two_body()
    # the grasp moves along the link (x) only: no y/z deflection, no rotation
    rates = np.zeros((2, 6))
    rates[1, 0] = 0.05
    # no contact forces: everything falls together, nothing sags
    traj = eo.simulate(model, y0, rates, TS_SMALL, forces=FREE_FALL)
    e = Experiment(TS_SMALL, traj.y, y0, rates, forces=FREE_FALL, sigma=1e-4)
    result = identify(model, e, STIFFNESS, init="model", progress=False)
    np.testing.assert_array_equal(result.identifiable, [True] + [False] * 5)
    stderr = np.asarray(result.stderr).ravel()
    assert np.isfinite(stderr[0]) and np.all(np.isinf(stderr[1:]))
    assert "NOT IDENTIFIABLE" in result.report()


@pytest.mark.slow  # a fit like the other one-experiment fits above
def test_unexcited_parameters_keep_the_model_values():
    """A motion along the link only, with noisy samples. The fit cannot see the
    five other stiffnesses; it keeps them at the model's values (a start 1.5x the
    truth here) and flags them. Before, the equation-error start had fitted the
    three rotational ones to the noise of the differentiated data (65, 210 and 333
    where the model holds 6, 7.5 and 9), and the fit returned them there."""
    model, y0 = _two_body()
    rates = np.zeros((2, 6))
    rates[1, 0] = 0.05
    traj = eo.simulate(model, y0, rates, TS_SMALL, forces=FREE_FALL)
    noise = 1e-5 * np.random.default_rng(3).normal(size=traj.y.shape)
    e = Experiment(TS_SMALL, traj.y + noise, y0, rates, forces=FREE_FALL, sigma=1e-5)
    truth = _flat(model, STIFFNESS)
    start = eqx.tree_at(STIFFNESS, model, 1.5 * model.stiffness)
    linear = _flat(equation_error(start, e, STIFFNESS, window=7), STIFFNESS)
    np.testing.assert_array_equal(linear[3:], 1.5 * truth[3:])
    assert abs(linear[0] / truth[0] - 1) < 0.05  # the one it sees, estimated
    result = identify(start, e, STIFFNESS, window=7, progress=False)
    np.testing.assert_array_equal(result.identifiable, [True] + [False] * 5)
    # (the translational two by the resolution test: above the Nyquist frequency)
    # (to the rounding of the fit's log coordinates)
    np.testing.assert_allclose(result.estimate[1:], 1.5 * truth[1:], rtol=1e-14)
    assert abs(result.estimate[0] - truth[0]) < 3 * float(result.stderr[0, 0])
    notes = " ".join(result.notes)
    assert "not determined by the samples for stiffness[0-1].psi" in notes
    assert "beyond what the samples resolve for stiffness[0-1].y" in notes


class _SolverFailingAboveLimit(diffrax.Tsit5):
    """Tsit5 that reports a solver failure when the simulated model's rotational
    stiffness c^{a2} exceeds `limit` (`simulate` passes the model as `args[0]`)."""

    limit: float = 10.0

    def step(self, terms, t0, t1, y0, args, solver_state, made_jump):
        *out, result = super().step(terms, t0, t1, y0, args, solver_state, made_jump)
        bad = args[0].stiffness[0, 4] > self.limit
        failed = diffrax.RESULTS.where(
            bad, diffrax.RESULTS.nonlinear_divergence, result
        )
        return (*out, failed)


# The stiffness the swing fits below estimate: c^{a2}, the others held at the truth.
C_A2 = np.eye(1, 6, 4, dtype=bool)


def _swing_fit(start_stiffness, swing=0.0, **kwargs):
    """`identify` of the two-body stiffness c^{a2} from `start_stiffness(truth)`, on
    noise-free data of the grasp swung at 2 rad/s about its x axis (and the object
    at `swing`), free of contact forces; returns the result and the true model.
    Every swing fit simulates with `_SolverFailingAboveLimit` (Tsit5 wherever
    c^{a2} <= 10) and fits c^{a2} alone: the fits share their compiled functions."""
    model, y0 = _two_body()
    rates = np.zeros((2, 6))
    rates[1, 4], rates[0, 4] = 2.0, swing
    traj = eo.simulate(model, y0, rates, TS_SMALL, forces=FREE_FALL)
    e = Experiment(TS_SMALL, traj.y, y0, rates, forces=FREE_FALL)
    start = eqx.tree_at(STIFFNESS, model, start_stiffness(model.stiffness))
    fit = identify(
        start,
        e,
        STIFFNESS,
        mask=C_A2,
        solver=_SolverFailingAboveLimit(),
        init="model",
        progress=False,
        **kwargs,
    )
    return fit, model


@pytest.mark.slow
def test_failing_trial_step_is_shortened_not_fatal():
    """Adam's first step moves the log-parameter by the learning rate: from
    c^{a2} = 2.5 (truth 5, the gradient says up), lr = 2 proposes 18.5, where the
    solver fails; the step must be halved (6.8) and the fit go on."""
    result, _ = _swing_fit(
        lambda k: k.at[0, 4].multiply(0.5),
        swing=-0.2,  # the object against the grasp
        method=optax.adam(2.0),
        max_steps=3,
    )
    assert result.n_failed_trials >= 1
    assert np.all(np.isfinite(result.loss_history))
    assert result.loss_history[-1] < result.loss_history[0]
    assert float(result.model.stiffness[0, 4]) < 10.0


@pytest.mark.slow  # the swing fit above (shared)
def test_plain_optimiser_with_tiny_steps_is_not_converged():
    """Adam's steps are its learning rate: at 1e-9, below xtol, every step is
    "small" although the start is far from the optimum. The fit must say so
    (stalled, the gradient named), not report convergence."""
    result, _ = _swing_fit(
        lambda k: k.at[0, 4].multiply(0.5), method=optax.adam(1e-9), max_steps=5
    )
    assert result.n_failed_trials == 0  # c^{a2} stays at 2.5: the solver is Tsit5
    assert not result.converged
    assert result.status == "stalled"
    assert "the gradient is not small" in result.reason


@pytest.mark.slow  # the swing fit above (shared)
def test_plain_optimiser_at_an_exact_fit_is_converged():
    """Gradient descent on one stiffness of noise-free data: at the optimum the
    loss falls to zero faster than its gradient, so the gradient test is against
    the start's loss and the fit is converged there, at the truth."""
    result, model = _swing_fit(
        lambda k: k.at[0, 4].multiply(1.2), method=optax.sgd(2.0), max_steps=60
    )
    assert result.n_failed_trials == 0  # c^{a2} stays below 10: the solver is Tsit5
    assert result.converged and result.status == "converged", result.reason
    np.testing.assert_allclose(result.estimate, model.stiffness[0, 4], rtol=1e-6)


# --- bad input ----------------------------------------------------------------


def _data():
    model, y0 = _two_body()
    ts = np.linspace(0, 0.1, 11)
    y = np.broadcast_to(np.asarray(y0), (11, 2, 6)).copy()
    return model, y0, ts, y


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(y=np.zeros((10, 2, 6))), "time grids do not match"),
        (dict(y=np.zeros((11, 2, 5))), r"shape \(times, bodies, 6\)"),
        (dict(ts=np.linspace(0, 1, 11)[::-1]), "strictly increasing"),
        (
            dict(y_init=np.zeros((3, 6))),
            r"Experiment.y_init and Experiment.y must have the same bodies",
        ),
        (dict(y_init=np.zeros(6)), r"y_init must have shape \(2, 6\)"),
        (dict(sigma=-1.0), "sigma must be positive"),
        (dict(sigma=np.ones(5)), "sigma must be a scalar"),
        (dict(forces=np.zeros((3, 6))), "forces must give shape"),
    ],
)
def test_bad_experiment(change, match):
    model, y0, ts, y = _data()
    args = dict(ts=ts, y=y, y_init=y0, ydot_init=np.zeros((2, 6)))
    args.update(change)
    with pytest.raises(ValueError, match=match):
        Experiment(**args)


def test_all_nan_channel_and_wrong_bodies():
    model, y0, ts, y = _data()
    y[:, 1, 3] = np.nan
    with pytest.raises(ValueError, match=r"y\[:, 1, 3\] is NaN in every sample"):
        Experiment(ts, y, y0, np.zeros((2, 6)))
    three = three_body_model()
    ok = Experiment(ts, np.nan_to_num(y), y0, np.zeros((2, 6)))
    with pytest.raises(ValueError, match="has 2 bodies but the model has 3"):
        identify(three, ok, STIFFNESS, progress=False)


def test_bad_identify_arguments():
    model, y0, ts, y = _data()
    e = Experiment(ts, y, y0, np.zeros((2, 6)))
    # the connected pairs are structure (a property), not a model leaf
    with pytest.raises(ValueError, match="where must return model leaves"):
        identify(model, e, lambda m: m.pairs, progress=False)
    with pytest.raises(ValueError, match="where must"):
        identify(model, e, lambda m: m.stiffness[0], progress=False)
    with pytest.raises(ValueError, match="method must be one of"):
        identify(model, e, STIFFNESS, method="newton", progress=False)
    with pytest.raises(ValueError, match="Log reparameterisation"):
        zero = eqx.tree_at(STIFFNESS, model, jnp.zeros((1, 6)))
        identify(zero, e, STIFFNESS, init="model", progress=False)
    with pytest.raises(ValueError, match="at least one Experiment"):
        identify(model, [], STIFFNESS, progress=False)
    for bad, match in (
        (dict(rcond=np.nan), "rcond must be a number in"),
        (dict(rcond=-1.0), "rcond must be a number in"),
        (dict(max_relative_stderr=np.nan), "max_relative_stderr must be a number"),
        (dict(max_relative_stderr=-1.0), "max_relative_stderr must be a number"),
    ):
        with pytest.raises(ValueError, match=match):
            identify(model, e, STIFFNESS, progress=False, **bad)
        with pytest.raises(ValueError, match=match):
            eo.gauss_newton_uncertainty(np.zeros(3), np.eye(3), np.ones(3), True, **bad)


# --- a fit that cannot leave its start ------------------------------------------

IDENTIFY_MODULE = importlib.import_module("elasticoop._identify.identify")


def _stalling(real, stall_calls):
    """`levenberg_marquardt` whose calls numbered in `stall_calls` (0-based) stop
    after the start's evaluation, as a fit does whose trial steps all fail to lower
    the loss (status "stalled")."""
    calls = []

    def fit(problem, u0, **kwargs):
        calls.append(None)
        if len(calls) - 1 not in stall_calls:
            return real(problem, u0, **kwargs)
        trace = real(problem, u0, **{**kwargs, "max_steps": 1})
        trace.status, trace.reason = "stalled", "stalled on purpose"
        return trace

    return fit


@pytest.mark.slow  # a fit from 2x off (as the recovery test above: compiled once)
def test_a_stalled_fit_is_run_again_from_the_other_start(two_body_runs, monkeypatch):
    """Noise-free data: the equation-error start fits better than the 2x-off model,
    but the fit from it stalls (forced here). `identify` fits again from the
    model's values, keeps that fit (lower loss) and lands on the truth."""
    model, runs = two_body_runs
    start = eqx.tree_at(STIFF_DAMP, model, (2 * model.stiffness, 2 * model.damping))
    real = optimisers.levenberg_marquardt
    monkeypatch.setattr(IDENTIFY_MODULE, "levenberg_marquardt", _stalling(real, {0}))
    result = identify(start, [e for _, e in runs], STIFF_DAMP, window=7, progress=False)
    assert any("started from the equation-error start" in n for n in result.notes)
    again = [n for n in result.notes if "never lowered its loss" in n]
    assert len(again) == 1 and "fitted again from the model's values" in again[0]
    assert again[0].endswith(", kept")
    np.testing.assert_array_equal(result.initial, _flat(start, STIFF_DAMP))
    assert result.converged, result.reason
    truth = _flat(model, STIFF_DAMP)
    np.testing.assert_allclose(result.estimate, truth, rtol=RECOVERY_RTOL)


@pytest.mark.slow  # two fits of one step each (compiled as above)
def test_a_fit_that_never_left_its_start_holds_nothing(two_body_runs, monkeypatch):
    """Every fit stalls at its start: nothing drifted, so nothing is held (even
    with every parameter flagged), the result is not converged, and the
    fall-back fit from the other start, no better, is not kept."""
    model, runs = two_body_runs
    start = eqx.tree_at(STIFF_DAMP, model, (2 * model.stiffness, 2 * model.damping))
    real = optimisers.levenberg_marquardt
    stall = _stalling(real, {0, 1})
    monkeypatch.setattr(IDENTIFY_MODULE, "levenberg_marquardt", stall)
    result = identify(
        start,
        [e for _, e in runs],
        STIFF_DAMP,
        window=7,
        max_relative_stderr=1e-12,
        progress=False,
    )
    assert result.status == "stalled" and not result.converged
    assert not np.any(result.identifiable)  # all flagged ...
    assert not np.any(result.held)  # ... none held
    assert any("not lower: kept the fit from the equation" in n for n in result.notes)
    assert not any(n.startswith("held ") for n in result.notes)


def test_holding_is_tested_against_the_noise():
    """The likelihood-ratio test: with unit noise, holding one parameter may raise
    the loss by half the 99 % quantile of chi-square with 1 degree of freedom
    (6.635 / 2); with noise level s, by s^2 times that."""
    _holding_fits = IDENTIFY_MODULE._holding_fits
    assert _holding_fits(10.0, 10.0 + 3.31, 1, 1.0)
    assert not _holding_fits(10.0, 10.0 + 3.32, 1, 1.0)
    assert _holding_fits(10.0, 10.0 + 4 * 3.31, 1, 2.0)
    assert not _holding_fits(10.0, 10.0 + 4 * 3.32, 1, 2.0)
    # 3 parameters: chi-square(3) 99 % quantile 11.345
    assert _holding_fits(0.0, 5.67, 3, 1.0) and not _holding_fits(0.0, 5.68, 3, 1.0)
    assert not _holding_fits(1.0, 1.0 + 1e-9, 1, np.nan)  # no noise level: exact


# --- parameters at the lower end of their range (bounded least squares) ----------


def _bound_problem(transform):
    from elasticoop._identify.parameters import free_parameters

    model, _ = _two_body()
    free = free_parameters(model, lambda m: m.damping, transform)
    return np.zeros(free.size, bool), free


@pytest.mark.parametrize("transform", ["log", "softplus"])
def test_at_bound_where_the_linearised_fit_goes_below_zero(transform):
    """A parameter whose one-dimensional linearised least-squares optimum (in the
    physical parameter) lies at or below the end of its range is at its bound;
    one whose optimum lies inside the range, or that the residuals ignore, is
    not. Without this a log-parameter crawls towards 0 (the crawl of the shipped
    36-parameter example)."""
    held, free = _bound_problem(transform)
    u = free.unconstrained(np.asarray(free.current(_two_body()[0])))
    p = np.asarray(free.physical(jnp.asarray(u)))
    dp_du = free.derivative(u)
    n = free.size
    # residuals r = J_p (p - p_opt): the linearised optimum is p_opt
    J_p = np.eye(n)
    p_opt = p.copy()
    p_opt[0] = -0.5 * p[0]  # beyond 0: at the bound
    p_opt[1] = -1e-6 * p[1]  # just below 0: at the bound
    p_opt[2] = 0.5 * p[2]  # inside the range: not
    J_p[3, 3] = 0.0  # the residuals ignore it: not
    r = J_p @ (p - p_opt)
    J_u = J_p * dp_du[None, :]
    mask = optimisers._at_bound(free, held, u, r, J_u)
    assert mask.tolist() == [True, True, False, False, False, False]
    # a held parameter is never at a bound of its own
    held = np.array([True] + [False] * (n - 1))
    assert not optimisers._at_bound(free, held, u, r, J_u)[0]
    # an unbounded (identity) parameter has no lower end
    held_id, free_id = _bound_problem("identity")
    assert not np.any(optimisers._at_bound(free_id, held_id, p, r, J_p))


def test_to_bound_sets_the_fraction_of_the_distance_to_zero():
    """Set at BOUND_FRACTION of the start's value: finite, also for a parameter
    whose value has underflowed to 0 (which counts as at its bound)."""
    held, free = _bound_problem("log")
    u0 = free.unconstrained(np.asarray(free.current(_two_body()[0])))
    u = u0.copy()
    u[5] = -800.0  # exp underflows to 0
    assert optimisers._at_bound(free, held, u, np.zeros(3), np.zeros((3, 6)))[5]
    mask = np.array([True, False, False, False, False, True])
    u_new = optimisers._to_bound(free, u, mask, u0)
    p, p0, p_new = (np.asarray(free.physical(jnp.asarray(x))) for x in (u, u0, u_new))
    np.testing.assert_allclose(p_new[mask], optimisers.BOUND_FRACTION * p0[mask])
    np.testing.assert_array_equal(p_new[~mask], p[~mask])


def test_unresolved_flags_what_the_samples_cannot_show():
    """A damping whose relaxation time (reduced mass / damping) is far below the
    sample interval, or a stiffness whose natural frequency is far above the
    Nyquist frequency, is beyond what the samples resolve; the values of the
    shipped plate lift (sampled every 10 ms) are not. The equation-error estimate
    of the shipped example had a damping of 8373 N s/m on a 0.2 kg grasp (a
    relaxation time of 2e-5 s): its fit started from a stiff simulation."""
    from elasticoop._identify.plausible import unresolved

    model, _ = _two_body()  # bodies of 1.0 and 0.3 kg: reduced mass 0.23 kg
    dt = 0.01
    stiff, damped = unresolved(model, dt)
    assert not np.any(stiff) and not np.any(damped)
    high = eqx.tree_at(
        lambda m: (m.stiffness, m.damping),
        model,
        (
            model.stiffness.at[0, 0].set(1e9),  # 2e4 Hz natural frequency
            model.damping.at[0, 1].set(8373.0),  # relaxation time 3e-5 s
        ),
    )
    stiff, damped = unresolved(high, dt)
    assert np.argwhere(stiff).tolist() == [[0, 0]]
    assert np.argwhere(damped).tolist() == [[0, 1]]
