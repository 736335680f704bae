"""Fits that go wrong say so: trials that all fail are no convergence, the step
budget of the simulations follows the fit, and an uncertainty that cannot be
computed does not lose the fit."""

import importlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from test_identify import STIFFNESS, TS_SMALL, _lift, _rates, _two_body

import elasticoop as eo
from elasticoop._identify import (
    Experiment,
    gauss_newton_uncertainty,
    identify,
    optimisers,
    residuals,
    step_budget,
)
from elasticoop._identify.parameters import free_parameters
from elasticoop._identify.residuals import make_problem

# the module of `identify` (the package's `identify` is the function)
identify_module = importlib.import_module("elasticoop._identify.identify")

# Noise-free data and a start that the fit must leave for the truth: the simulator
# runs at rtol 1e-8, far below it.
RECOVERY_RTOL = 1e-6


def _experiment(truth):
    """One noise-free motion of `truth` (the two-body model of test_identify) from
    seeded initial rates, with the sigma of its other one-experiment fits."""
    model, y0 = _two_body()
    rates = _rates(model, np.random.default_rng(7))
    traj = eo.simulate(truth, y0, rates, TS_SMALL, forces=_lift(model))
    return Experiment(TS_SMALL, traj.y, y0, rates, forces=_lift(model), sigma=1e-5)


def _with_stiffness(model, stiffness):
    return eqx.tree_at(STIFFNESS, model, jnp.asarray(stiffness))


@pytest.fixture
def small_budget(monkeypatch):
    """Step budgets of 128 and 256 instead of at least 4096: the two-body runs
    take 30-140 steps, so a budget of 1.5x the current point's steps (at least
    128, rounded up to a power of 2) shows what the budget does to a fit, and
    the fits below share their compiled functions."""
    monkeypatch.setattr(step_budget, "STEP_BUDGET_FACTOR", 1.5)
    monkeypatch.setattr(step_budget, "MIN_BUDGET", 128)


@pytest.mark.slow  # a fit (compiled once for the fits of this module)
def test_all_trials_failing_is_not_convergence(small_budget):
    """From 1e-8 times the stiffness the Levenberg-Marquardt trial points lie
    many orders of magnitude stiffer (steps of 1e4 and more in log space): the
    stiffness overflows, and every trial run is refused at once as a model out of
    range (a stiffness that is not finite: `Status.INVALID_MODEL`). The fit never
    moved: it must not say it converged, and the reason must say why the trials
    failed."""
    model, _ = _two_body()
    soft = _with_stiffness(model, 1e-8 * model.stiffness)
    result = identify(
        soft, _experiment(model), STIFFNESS, init="model", max_steps=14, progress=False
    )
    assert not result.converged
    assert result.status == "failed"
    assert result.n_failed_trials == 13
    assert "every trial step (13) failed to simulate" in result.reason
    assert "(13 stopped with status INVALID_MODEL)" in result.reason
    assert "the loss never moved from the start" in result.reason
    # the start, through u = log p and back
    np.testing.assert_allclose(result.estimate, result.initial, rtol=1e-14)
    assert len(result.loss_history) == 1


@pytest.mark.slow  # a fit
def test_step_budget_follows_the_fit(small_budget, monkeypatch):
    """The start (0.4x the stiffness of the data's model) takes 82 steps, so its
    budget is 128; the truth takes 135. The budget must grow as the fit stiffens,
    and the fit reach the truth (with a budget fixed at the start's, every trial
    near the truth failed and the fit stopped short). The budget is a traced
    value: the plain simulations compile once whatever it is."""
    model, _ = _two_body()
    truth = _with_stiffness(model, 1.2 * model.stiffness)
    start = _with_stiffness(model, 0.4 * model.stiffness)
    traces = eqx.debug.get_num_traces(residuals._sensitivities)
    plain_traces = eqx.debug.get_num_traces(residuals.evaluate)
    budgets = []  # the step budget of each plain evaluation, in order
    evaluate = residuals.evaluate

    def recorded(u, problem):
        budgets.append(problem.max_steps)
        return evaluate(u, problem)

    for module in (identify_module, optimisers, residuals):
        monkeypatch.setattr(module, "evaluate", recorded)
    result = identify(
        start, _experiment(truth), STIFFNESS, init="model", max_steps=40, progress=False
    )
    assert result.converged, result.reason
    # the simulations with and without sensitivities compile once whatever the
    # budget, and the start ran under the budget of 128 steps that the fit from
    # it was given (not under max_steps)
    assert eqx.debug.get_num_traces(residuals._sensitivities) <= traces + 1
    assert eqx.debug.get_num_traces(evaluate) <= plain_traces + 1
    assert budgets[0] == 128 and set(budgets) == {128, 256}
    np.testing.assert_allclose(
        result.estimate, np.ravel(truth.stiffness), rtol=RECOVERY_RTOL
    )
    assert any("step budget raised from 128 to 256" in n for n in result.notes)


@pytest.mark.slow  # a fit (compiled for the test above)
def test_a_start_needing_more_than_a_cheap_starts_budget_is_simulated_again(
    small_budget, monkeypatch
):
    """The starts are simulated under the budget that a start needing few steps
    gets (`MIN_BUDGET`). The start here takes 82 steps, more than a budget of 64:
    it must be simulated again under the simulation settings' `max_steps` (not
    refused as a start that fails), and the fit given the budget its 82 steps
    call for (128), then reach the truth."""
    monkeypatch.setattr(step_budget, "MIN_BUDGET", 64)
    model, _ = _two_body()
    truth = _with_stiffness(model, 1.2 * model.stiffness)
    start = _with_stiffness(model, 0.4 * model.stiffness)
    result = identify(
        start, _experiment(truth), STIFFNESS, init="model", max_steps=40, progress=False
    )
    assert result.converged, result.reason
    np.testing.assert_allclose(
        result.estimate, np.ravel(truth.stiffness), rtol=RECOVERY_RTOL
    )
    assert any("simulations limited to 128 solver steps" in n for n in result.notes)


@pytest.mark.slow  # a fit of two steps (compiled for the test above)
def test_uncertainty_failure_keeps_the_fit(small_budget):
    """A log-parameter below the smallest normal float (as a fit drives one
    that the data push below zero, e.g. with sigma far below the noise) is 0 in
    compiled code, with dp/du = 0: its Jacobian column in physical units is 0/0.
    The fit must come back, with NaN standard errors saying why."""
    if float(jax.jit(jnp.exp)(jnp.log(1e-310))) != 0.0:
        pytest.skip("this platform keeps subnormal floats in compiled code")
    model, _ = _two_body()
    start = _with_stiffness(model, model.stiffness.at[0, 0].set(1e-310))
    with pytest.warns(RuntimeWarning, match="uncertainty not computed"):
        result = identify(
            start, _experiment(model), STIFFNESS, init="model", max_steps=2
        )
    assert result.estimate[0] == 0.0
    assert np.all(np.isnan(result.uncertainty.stderr))
    assert "stiffness[0-1].x" in result.uncertainty.reason
    assert any("dp/du is 0" in n for n in result.notes)
    assert "uncertainty not computed" in result.report()
    np.testing.assert_array_equal(np.ravel(result.model.stiffness), result.estimate)


def _well_posed():
    rng = np.random.default_rng(0)
    return rng.normal(size=20), rng.normal(size=(20, 3)), np.array([1.0, 2.0, 3.0])


def test_uncertainty_of_a_non_finite_jacobian_is_nan_with_a_reason():
    residual, J, p = _well_posed()
    J[:, 1] = np.nan
    with pytest.warns(RuntimeWarning, match="non-finite entries for b"):
        unc = gauss_newton_uncertainty(
            residual, J, p, noise_known=True, names=("a", "b", "c")
        )
    assert np.all(np.isnan(unc.stderr)) and np.all(np.isnan(unc.correlation))
    assert not np.any(unc.identifiable)
    assert unc.reason.startswith("uncertainty not computed")


def test_uncertainty_of_extreme_jacobians_does_not_overflow():
    """Scaling J by c scales the standard errors by 1/c (noise known), however
    large c is; the squares of the singular values overflow at c = 1e160."""
    residual, J, p = _well_posed()
    reference = gauss_newton_uncertainty(residual, J, p, noise_known=True)
    with np.errstate(over="ignore"):  # the Fisher information is inf there
        scaled = gauss_newton_uncertainty(residual, 1e160 * J, p, noise_known=True)
    np.testing.assert_allclose(scaled.stderr * 1e160, reference.stderr, rtol=1e-12)
    np.testing.assert_allclose(scaled.correlation, reference.correlation, rtol=1e-12)
    assert scaled.reason == ""


def test_step_budget_policy():
    """8x the steps of the current point, at least 4096, a power of 2, or the
    start's 100 000 where that is more than half of it; raised only when an
    accepted point needs more, and never when the caller fixed it."""
    model, y0 = _two_body()
    e = Experiment(TS_SMALL, np.zeros((51, 2, 6)), y0, np.zeros((2, 6)))
    free = free_parameters(model, STIFFNESS)
    problem = make_problem(model, free, [e], eo.SimulationOptions(max_steps=100_000))
    assert [
        step_budget.step_budget(n) for n in (30, 600, 1000, 4096, 7196, 20_000)
    ] == [4096, 8192, 8192, 32768, 100_000, 100_000]
    budget = step_budget.StepBudget(adaptive=True)
    problem = budget.start(problem, 30)
    assert problem.step_budget == 4096
    # reverse-mode gradients take it as the static max_steps (buffers sized by it)
    static = residuals.with_static_budget(problem)
    assert static.step_budget is None and static.options.max_steps == 4096
    assert residuals.with_static_budget(static) is static
    assert budget.follow(problem, 512, 3) is problem
    raised = budget.follow(problem, 513, 4)
    assert raised.step_budget == 8192 and budget.raised_to == 8192
    assert "raised from 4096 to 8192 at iteration 4" in budget.notes[-1]
    fixed = step_budget.StepBudget(adaptive=False)
    assert fixed.follow(fixed.start(problem, 30), 10_000, 2) is problem
    # at most the simulation options' max_steps
    assert budget.follow(problem, 7196, 5).max_steps == 100_000
