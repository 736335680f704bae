"""Identification from measured motion alone: forces from a scenario file (or any
force pytree), the initial state taken from the data and estimated with the
parameters, and parameters the data do not determine held at their start."""

import textwrap

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest

import elasticoop as eo
from elasticoop._identify import (
    Experiment,
    IdentificationResult,
    Uncertainty,
    savitzky_golay,
)
from elasticoop._identify.experiment import batch_experiments
from elasticoop._identify.initial_state import initial_state_from_data
from elasticoop._identify.uncertainty import gauss_newton_uncertainty

# An estimate counts as recovered within this many of its standard errors (the
# standard errors are calibrated: see test_identify.py); with 5 + 24 checks of a
# Gaussian error the chance of a miss is below 0.2 % (and the seed is fixed).
WITHIN_STDERRS = 4.0

# Two bodies, RPY angles at the identity, the grasp under pose tracking; the truth
# starts with a nonzero velocity and angle rate on both bodies. The link lies along
# x at its rest length, so its transverse stiffness c^y is barely excited (a link is
# stiff only along itself at rest length): the data do not determine it.
SCENARIO = """
name = "two-body grasp"

[model]
kind = "mobile"
convention = "rpy"

[[bodies]]
name = "box"
mass = 1.0
inertia = [0.02, 0.03, 0.04]

[[bodies]]
name = "grasp"
mass = 0.3
inertia = [2.0e-3, 2.0e-3, 2.0e-3]

[[connections]]
bodies = ["box", "grasp"]
stiffness = [400.0, 500.0, 600.0, 4.0, 5.0, 6.0]
damping = [0.5, 0.5, 0.5, 0.005, 0.005, 0.005]

[initial.box]
position = [0.0, 0.0, 1.0]
angles = { radians = [0.0, 0.0, 0.0] }
velocity = [0.03, -0.04, 0.05]
angle_rates = { radians = [0.3, -0.2, 0.25] }

[initial.grasp]
position = [0.4, 0.0, 1.0]
angles = { radians = [0.0, 0.0, 0.0] }
velocity = [-0.02, 0.03, 0.0]
angle_rates = { radians = [-0.2, 0.3, 0.1] }

[forces.pose_tracking]
lift_height = 0.02
lift_time = 0.2
kp = [2.0e3, 2.0e3, 2.0e3, 10.0, 10.0, 10.0]
kd = [20.0, 20.0, 20.0, 0.1, 0.1, 0.1]
feedforward = "weight"

[time]
stop = 0.2
samples = 41
"""

SIGMA = 1e-5  # noise on every coordinate [m, rad]
STIFFNESS = lambda m: m.stiffness  # noqa: E731
TRANSVERSE = 1  # the index of c^y among the six stiffnesses


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    path = tmp_path_factory.mktemp("scenario") / "two_body.toml"
    path.write_text(textwrap.dedent(SCENARIO))
    return eo.load_scenario(path)


@pytest.fixture(scope="module")
def measured(scenario):
    """The scenario's motion with Gaussian noise: the data, without the initial
    state."""
    truth = scenario.simulate()
    rng = np.random.default_rng(0)
    return np.asarray(truth.y) + SIGMA * rng.normal(size=truth.y.shape)


def _fit(scenario, e, **settings):
    """The stiffness fitted to `e` from 30 % off, with the initial state estimated
    (not given) and the parameters named by the scenario's bodies: every fit of
    this module, so that they share their compiled functions."""
    start = eqx.tree_at(STIFFNESS, scenario.model, 1.3 * scenario.model.stiffness)
    return eo.identify(
        start,
        e,
        STIFFNESS,
        init="model",
        fit_initial="state",
        body_names=scenario.names,
        progress=False,
        **settings,
    )


@pytest.fixture(scope="module")
def fits(scenario, measured):
    """One fit from 30 % off, with the initial state estimated (not given), and the
    same fit without holding (compiled once: the held set is a traced value)."""
    e = Experiment(scenario.ts, measured, forces=scenario.forces, sigma=SIGMA)
    held = _fit(scenario, e, hold_unidentifiable=True)
    free = _fit(scenario, e, hold_unidentifiable=False)
    return e, held, free


# --- forces that hold Python numbers ---------------------------------------------


class _Push(eo.AbstractForce):
    """A constant push along x whose size is a Python float (a constant leaf)."""

    size: float

    def __call__(self, t, y, ydot):
        return jnp.zeros((1, 6)).at[0, 0].set(self.size)


def _small_experiment(forces):
    ts = np.linspace(0.0, 0.1, 11)
    y = np.zeros((11, 2, 6))
    return Experiment(ts, y, np.zeros((2, 6)), np.zeros((2, 6)), forces=forces)


def test_experiments_batch_with_forces_holding_python_numbers():
    """A force holding Python floats (not arrays) used to crash the grouping of
    experiments ('float' object has no attribute 'shape'): equal constants batch
    together, different ones apart, and the float stays a constant."""
    experiments = [_small_experiment(_Push(s)) for s in (1.0, 1.0, 2.0)]
    groups = batch_experiments(experiments)
    assert [indices for indices, _ in groups] == [[0, 1], [2]]
    stacked = groups[0][1]
    assert stacked.forces.size == 1.0
    assert stacked.y.shape == (2, 11, 2, 6)


def test_pose_tracking_holds_arrays_whatever_it_is_given():
    force = eo.PoseTracking(
        y_ref=[[0.4, 0.0, 1.0, 0.0, 0.0, 0.0]],
        feedforward=[[0.0, 0.0, 12.0, 0.0, 0.0, 0.0]],
        kp=[1.0] * 6,
        kd=[0.1] * 6,
        height=0.02,
        duration=0.2,
    )
    for leaf in jax.tree.leaves(force):
        assert isinstance(leaf, jax.Array) and leaf.dtype == jnp.float64
    assert force.height.shape == () and force.kp.shape == (6,)
    # and it batches like any array force
    groups = batch_experiments([_small_experiment(force)] * 2)
    assert groups[0][1].forces.height.shape == (2,)


# --- the initial state from the data -----------------------------------------------


def test_initial_state_from_data_is_exact_on_polynomials():
    """Motion that is a polynomial of degree <= polyorder: the differentiator's rate
    at t0 is exact, and the first sample is the initial position."""
    ts = np.linspace(0.5, 1.0, 26)
    coeff = np.random.default_rng(3).normal(size=(4, 2, 6))  # cubic per coordinate
    s = ts - ts[0]
    y = sum(coeff[k][None] * s[:, None, None] ** k for k in range(4))
    y0, ydot0 = initial_state_from_data(ts, y, window=11, polyorder=3)
    np.testing.assert_allclose(y0, coeff[0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(ydot0, coeff[1], rtol=1e-8, atol=1e-9)
    # an Experiment without an initial state takes these
    e = Experiment(ts, y, window=11, polyorder=3)
    np.testing.assert_array_equal(e.y_init, y0)
    np.testing.assert_array_equal(e.ydot_init, ydot0)
    # a given part is kept as given
    e = Experiment(ts, y, np.ones((2, 6)), window=11, polyorder=3)
    np.testing.assert_array_equal(e.y_init, np.ones((2, 6)))
    np.testing.assert_array_equal(e.ydot_init, ydot0)
    # a measured rate gives the initial rate as its first sample
    measured = np.full_like(y, 7.0)
    e = Experiment(ts, y, ydot=measured, window=11, polyorder=3)
    np.testing.assert_array_equal(e.ydot_init, measured[0])
    # a given state of other bodies than the samples': both are named
    with pytest.raises(
        ValueError,
        match=r"Experiment.y_init and Experiment.y must have the same bodies, got "
        r"Experiment.y_init of shape \(3, 6\) .* Experiment.y of shape \(2, 6\)",
    ):
        Experiment(ts, y, np.ones((3, 6)), window=11, polyorder=3)


def test_initial_state_from_data_refuses_missing_samples_and_short_data():
    ts = np.linspace(0.0, 1.0, 30)
    y = np.zeros((30, 2, 6))
    y[3, 1, 4] = np.nan
    with pytest.raises(ValueError, match=r"Experiment.y\[:21, 1, 4\].*missing"):
        Experiment(ts, y)
    with pytest.raises(ValueError, match="window .* longer than the data"):
        Experiment(ts[:10], y[:10])
    y = np.zeros((30, 2, 6))
    y[0, 0, 0] = np.nan  # the first sample itself
    with pytest.raises(ValueError, match=r"y\[:21, 0, 0\] \(body 0, coordinate 0\)"):
        initial_state_from_data(ts, y)


def test_fit_initial_and_hold_are_checked_before_simulating(scenario):
    e = _small_experiment(None)
    model = scenario.model
    with pytest.raises(ValueError, match="fit_initial must be one of"):
        eo.identify(model, e, STIFFNESS, fit_initial="velocity", progress=False)
    with pytest.raises(ValueError, match="hold_unidentifiable must be True or"):
        eo.identify(model, e, STIFFNESS, hold_unidentifiable="yes", progress=False)
    with pytest.raises(ValueError, match="body_names must be 2 distinct names"):
        eo.identify(model, e, STIFFNESS, body_names=["a"], progress=False)


# --- uncertainty with nuisance parameters ----------------------------------------


def test_uncertainty_is_marginal_over_nuisance_parameters():
    """Linear least squares: the standard errors of p with x estimated too are the
    p block of the joint covariance (J^T J)^-1, noise estimated from N - n_p - n_x
    degrees of freedom."""
    rng = np.random.default_rng(5)
    J = rng.normal(size=(40, 5))
    J[:, 3] += 0.8 * J[:, 0]  # a nuisance column correlated with a parameter
    r = rng.normal(size=40)
    p = np.array([2.0, -3.0, 0.5])
    unc = gauss_newton_uncertainty(r, J[:, :3], p, noise_known=False, nuisance=J[:, 3:])
    s2 = r @ r / (40 - 5)
    joint = s2 * np.linalg.inv(J.T @ J)
    np.testing.assert_allclose(unc.stderr, np.sqrt(np.diag(joint))[:3], rtol=1e-10)
    np.testing.assert_allclose(unc.covariance, joint[:3, :3], rtol=1e-10)
    # without the nuisance columns the errors are those of p alone (smaller)
    alone = gauss_newton_uncertainty(r, J[:, :3], p, noise_known=True)
    np.testing.assert_allclose(
        alone.stderr, np.sqrt(np.diag(np.linalg.inv(J[:, :3].T @ J[:, :3]))), 1e-10
    )


def test_report_says_which_parameters_were_held():
    """The report of a fit with a held parameter (no fit needed to format it)."""
    unc = Uncertainty(
        stderr=np.array([1.0, np.inf]),
        covariance=np.full((2, 2), np.nan),
        correlation=np.full((2, 2), np.nan),
        fisher=np.zeros((2, 2)),
        singular_values=np.ones(1),
        directions=np.ones((2, 1)),
        identifiable=np.array([True, False]),
        noise_scale=1.0,
    )
    result = IdentificationResult(
        model=None,
        stderr=None,
        loss_history=np.array([2.0, 1.0]),
        converged=True,
        status="converged",
        reason="test",
        names=("k.x", "k.y"),
        estimate=np.array([400.0, 650.0]),
        initial=np.array([520.0, 650.0]),
        start=np.array([520.0, 650.0]),
        uncertainty=unc,
        n_iterations=1,
        n_simulations=2,
        n_rejected=0,
        n_failed_trials=0,
        method="m",
        wall_time=0.0,
        held=np.array([False, True]),
        initial_state_names=("experiment[0].ydot_init.box.x",),
        initial_state_estimate=np.array([0.03]),
        initial_state_stderr=np.array([1e-4]),
    )
    text = result.report()
    assert "k.y" in text and "held at its start value (not fitted)" in text
    # the other estimate's standard error is conditional on the held value
    assert "conditional on the held values" in text
    assert "1 of them held at their start values" in text
    assert "experiment[0].ydot_init.box.x" in text
    assert [row.held for row in result.table] == [False, True]


# --- one fit from the measured motion alone ---------------------------------------


@pytest.mark.slow  # one fit with forward-mode sensitivities (compiled once here)
def test_fit_recovers_parameters_and_initial_state_not_given(scenario, fits):
    """Forces from a scenario file, no initial state given: the fit recovers the
    identifiable stiffnesses and the initial velocity within WITHIN_STDERRS
    standard errors (which are small), although its start from the data was off."""
    e, result, _ = fits
    assert result.converged, result.reason
    truth = np.asarray(scenario.model.stiffness).ravel()
    ok = result.identifiable
    assert np.sum(ok) == 5 and not ok[TRANSVERSE]
    stderr = result.uncertainty.stderr
    assert np.all(stderr[ok] < 0.02 * truth[ok])  # the check below is not vacuous
    assert np.all(np.abs(result.estimate - truth)[ok] <= WITHIN_STDERRS * stderr[ok])
    y_init, ydot_init = result.initial_states[0]
    se = result.initial_state_stderr.reshape(2, 2, 6)  # positions, rates
    true_rates = np.asarray(scenario.ydot_init)
    assert np.all(np.abs(ydot_init - true_rates) <= WITHIN_STDERRS * se[1])
    assert np.all(np.abs(y_init - scenario.y_init) <= WITHIN_STDERRS * se[0])
    # the differentiator's start was far off, by many standard errors
    start_error = np.abs(np.asarray(e.ydot_init) - true_rates)
    assert np.max(start_error / se[1]) > 100
    assert "experiment[0].ydot_init.grasp.roll" in result.initial_state_names
    np.testing.assert_allclose(
        result.initial_state_estimate[12:], ydot_init.ravel(), rtol=1e-15
    )


@pytest.mark.slow  # the fit above (shared)
def test_unidentifiable_stiffness_is_held_at_its_start(scenario, fits):
    """c^y is not excited enough to be determined: it comes back at its start
    value (30 % above the truth), flagged and said to be held; without holding,
    the optimiser moves it to wherever the noise puts it."""
    _, result, free = fits
    start = 1.3 * np.asarray(scenario.model.stiffness).ravel()
    assert result.held.tolist() == [k == TRANSVERSE for k in range(6)]
    assert result.estimate[TRANSVERSE] == start[TRANSVERSE]
    assert float(result.model.stiffness[0, TRANSVERSE]) == start[TRANSVERSE]
    report = result.report()
    # the parameters are named by the scenario's bodies (box, grasp)
    name = "stiffness[box-grasp].y"
    assert result.names[TRANSVERSE] == name
    assert name in report and "held at its start value (not fitted)" in report
    assert any(f"held {name} at their start values" in n for n in result.notes)
    # the same fit without holding: flagged, but not at its start
    assert not free.identifiable[TRANSVERSE] and not free.held[TRANSVERSE]
    assert abs(free.estimate[TRANSVERSE] / start[TRANSVERSE] - 1) > 1e-3
    # holding leaves the other estimates within a fraction of their errors
    ok = result.identifiable
    diff = np.abs(result.estimate - free.estimate)[ok]
    assert np.all(diff < result.uncertainty.stderr[ok])


@pytest.mark.slow  # one more fit of the problem above (compiled already)
def test_holding_values_the_data_reject_is_refused(scenario, fits):
    """Every stiffness flagged (a threshold no estimate meets): holding them all at
    their start, 30 % off, raises the loss far beyond the noise, so none is held
    and the estimates are those of the fit without holding."""
    e, _, free = fits
    result = _fit(scenario, e, max_relative_stderr=1e-12, hold_unidentifiable=True)
    assert not np.any(result.identifiable) and not np.any(result.held)
    np.testing.assert_array_equal(result.estimate, free.estimate)
    refused = [n for n in result.notes if "more than the noise explains" in n]
    assert len(refused) == 1 and "stiffness[box-grasp].x" in refused[0]


def test_savitzky_golay_marks_estimates_of_windows_with_missing_samples():
    """A missing sample makes NaN exactly the estimates whose window holds it (the
    first or last `window` samples for the estimates within half a window of the
    ends), instead of failing; the others stay exact on a polynomial of degree
    <= polyorder."""
    ts = np.linspace(0.0, 1.0, 41)
    y = 1.0 + 2.0 * ts - 3.0 * ts**2
    data = y.copy()
    data[[1, 20]] = np.nan
    smooth, rate = savitzky_golay(data, ts, window=7, polyorder=2, derivs=(0, 1))
    spoilt = np.zeros(41, dtype=bool)
    # samples 0-2 are fitted to the first 7 samples, 3 and 4 to windows centred on
    # them (0-6, 1-7): all hold sample 1; the windows of 17-23 hold sample 20
    spoilt[:5] = True
    spoilt[17:24] = True
    np.testing.assert_array_equal(np.isnan(rate), spoilt)
    np.testing.assert_array_equal(np.isnan(smooth), spoilt)
    np.testing.assert_allclose(smooth[~spoilt], y[~spoilt], atol=1e-12)
    np.testing.assert_allclose(rate[~spoilt], (2.0 - 6.0 * ts)[~spoilt], atol=1e-9)
