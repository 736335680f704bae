"""`identify`: fit free model parameters to measured motion (output error)."""

import dataclasses
import time
import warnings
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._custom_types import Validated
from .._naming import body_names as checked_body_names
from .._options import GIMBAL_TOL, LINK_TOL, SimulationOptions
from .._status import Status
from .equation_error import estimate_by_equation_error
from .experiment import check_experiments
from .initial_state import fitted_parts, initial_rule, initial_state_names
from .misfit import MISFIT_THRESHOLD, misfit_check
from .optimisers import Trace, levenberg_marquardt, optax_minimise
from .parameters import free_parameters
from .plausible import RESOLUTION, unresolved
from .residuals import (
    FitProblem,
    evaluate,
    initial_states,
    make_problem,
    residuals_and_jacobian,
    with_held,
    with_step_budget,
)
from .result import IdentificationResult
from .step_budget import START_MAX_STEPS, StepBudget, step_budget
from .uncertainty import (
    Uncertainty,
    check_identifiability_thresholds,
    gauss_newton_uncertainty,
    with_held_stderr,
)

METHODS = ("levenberg-marquardt", "lbfgs")
# Significance level of the test that decides whether parameters flagged not
# identifiable may be held at their start (`_holding_fits`).
HOLD_TEST_LEVEL = 0.01
DEFAULT_MAX_ITERATIONS = 100
# What a pose tracking's feedforward is during a fit (`identify`'s `feedforward`).
FEEDFORWARD_RULES = ("frozen", "rest")


def identify(
    model,
    experiments,
    where,
    *,
    method="levenberg-marquardt",
    init: str = "equation_error",
    transform="log",
    max_iterations: int | None = None,
    xtol: float = 1e-8,
    ftol: float = 1e-12,
    progress: bool = True,
    options: SimulationOptions | None = None,
    solver: diffrax.AbstractSolver | None = None,
    gimbal_tol: float = GIMBAL_TOL,
    link_tol: float = LINK_TOL,
    window: int = 21,
    polyorder: int = 4,
    rcond: float = 1e-8,
    max_relative_stderr: float = 0.5,
    mask=None,
    initial: Validated[str] = "auto",
    feedforward: Validated[str] = "frozen",
    fit_initial: Validated[str] = "none",
    hold_unidentifiable: Validated[bool] = False,
    misfit_threshold: float = MISFIT_THRESHOLD,
    body_names=None,
    max_steps: int | None = None,
    sim_rtol: float | None = None,
    sim_atol: float | None = None,
    max_sim_steps: int | None = None,
) -> IdentificationResult:
    """Fit the free parameters of `model` to measured motion by output error.

    Minimises $\\tfrac12\\sum r^2$ over the experiments, $r$ the simulated minus the
    measured $Y$ (and $\\dot Y$ where measured) divided by the noise level
    `Experiment.sigma`, missing samples left out. The free leaves are
    reparameterised ($p = e^u$ by default), so they stay positive.

    **Arguments:**

    - `model`: an `ImmobileModel` or `MobileModel`; the values of the free leaves
      are the start (or the expansion point of the equation-error start), all
      other leaves are known.
    - `experiments`: an `Experiment` or a sequence of them; those of equal shapes
      are simulated together under `jax.vmap`.
    - `where`: selects the free leaves like `equinox.tree_at`, e.g.
      `lambda m: (m.stiffness, m.damping)`.
    - `method`: `"levenberg-marquardt"` (default: `optimistix.LevenbergMarquardt`
      with forward-mode sensitivities, `diffrax.ForwardMode`), `"lbfgs"`
      (`optax.lbfgs` with reverse-mode gradients through `simulate`), or any optax
      optimiser, e.g. `optax.adam(1e-2)`.
    - `init`: `"equation_error"` (default) or `"model"`. With
      `"equation_error"` the fit starts from the `equation_error` estimate
      (entries it does not determine by the thresholds below, entries outside
      the transform's range, and stiffnesses and dampings beyond what the
      samples resolve, `plausible.unresolved`, taken from the model) when its
      simulated loss is not above that of the model's values, and from the
      model's values otherwise: with noisy data the differentiated samples can
      spoil the linear estimate, and the start that fits better is kept (a note
      in the result says which). If the fit from that start stops without
      lowering its loss (other than at `max_iterations`; e.g. a stiff start whose
      sensitivities are too inaccurate to give a descent direction), it is run
      again from the other start, and the fit with the lower loss is returned
      (a note says so).
    - `transform`: reparameterisation of the free leaves: `"log"` (default),
      `"softplus"`, `"identity"`, an `AbstractTransform` such as
      `Bounded(lower, upper)`, or one of these per selected leaf.
    - `max_iterations`: the most optimiser iterations (Levenberg-Marquardt: trial
      steps); default 100. (`max_steps` is its deprecated name.)
    - `xtol`, `ftol`: the fit has converged after an accepted step that changes
      no entry of $u$ by more than `xtol` (for log-parameters: a relative change),
      or lowers the loss by at most `ftol` times the loss; or when a dozen trial
      steps in a row, in an ever smaller trust region, find no lower loss. A plain
      optax optimiser (no line search), whose steps its learning rate sets, has
      converged only where no entry of the loss's gradient in $u$ exceeds
      `PLAIN_GTOL` (1e-6) times the loss at the start as well; otherwise it
      stops as `"stalled"`.
    - `progress`: print iteration, loss and gradient norm while fitting.
    - `options`: the `SimulationOptions` of every simulation of the fit (solver,
      `rtol`, `atol`, `max_steps`, `gimbal_tol`, `link_tol`; default: `tsit5`,
      1e-8, 1e-10, 100 000). The start's simulations may take `max_steps` solver
      steps, every later one 8x the steps the current point needed (at least
      4096, rounded up to a power of 2, so that fits of similar problems share
      their compiled functions; raised, and the fit's functions compiled anew,
      whenever an accepted point needs more than an eighth of it, up to
      `max_steps`): a trial point that needs more is far off (much stiffer) and
      is rejected like a failed simulation, instead of costing a long
      integration.
    - `solver`, `gimbal_tol`, `link_tol`: set those of the default options
      (without `options`). `sim_rtol`, `sim_atol`, `max_sim_steps` are deprecated
      (a `DeprecationWarning`): pass `options`; a given `max_sim_steps` is the
      budget of every simulation.
    - `window`, `polyorder`: Savitzky-Golay smoothing of the equation-error start.
    - `rcond`, `max_relative_stderr`: identifiability thresholds (see
      `gauss_newton_uncertainty`).
    - `mask`: fit only some entries of the selected leaves: boolean arrays in the
      structure of `where(model)`, each shaped like its leaf (`None` for a whole
      leaf), e.g. `(k_mask, None)`; the other entries keep the model's values,
      and `stderr` is NaN there. Default: every entry is free.
    - `initial`: how each experiment's initial state is set. What the
      experimenter applied (the experiment's forces, e.g. a feedforward the
      scenario derived from its model) stays as given; what the system did
      follows the parameters:
      - `"auto"` (default): experiments that started at rest in static
        equilibrium (`Experiment.rest`, set by `load_experiment` for a scenario
        with `[initial] from = "equilibrium"`) start from the rest state of the
        parameters being evaluated, recomputed at every evaluation of the fit
        (`rest_state`; its sensitivities by the implicit function theorem), the
        held coordinates at their poses in `y_init`, at rest; the others from
        their `y_init`, `ydot_init`.
      - `"equilibrium"`: every experiment so (those without `Experiment.rest`
        with the contact bodies held).
      - `"frozen"`: every experiment from its `y_init`, `ydot_init` as given
        (the old behaviour: an equilibrium of the starting model stays fixed,
        which biases the fit when the data started from the equilibrium of other
        parameters).
      - `"data"`: from each experiment's first samples (`initial_state_from_data`
        with `window`, `polyorder`).
      - `"fitted"`: estimated with the parameters (`fit_initial="state"`).
      A note in the result says which rule was applied.
    - `feedforward`: `"frozen"` (default): the experiments' forces are what the
      experimenter applied, numbers that do not change with the parameters
      (e.g. a feedforward the scenario derived from its nominal model with
      `"hold"`). `"rest"`: for experiments at rest with pose tracking, the
      feedforward is the force that holds the contact bodies in the rest state
      of the parameters evaluated, $\\partial\\Pi/\\partial Y_i - G_i$,
      recomputed with it: right when the manipulators held the grasps still
      with whatever force that took (as `elasticoop run` of a scenario with
      `feedforward = "hold"` simulates its own model), wrong when the
      experimenter commanded the nominal numbers.
    - `fit_initial`: which part of each experiment's initial state is estimated
      together with the parameters: `"none"` (default: `Experiment.y_init` and
      `ydot_init` are known), `"rates"` ($\\dot Y(t_0)$), `"positions"`
      ($Y(t_0)$) or `"state"` (both). The experiment's values (given, or taken
      from the data by the differentiator) are the start; the estimates are in
      `result.initial_states`, their standard errors in
      `result.initial_state_stderr`, and the parameters' standard errors are
      marginal over them (see `initial_state`).
    - `hold_unidentifiable`: `False` (default) keeps every parameter in the fit:
      the ones the data do not determine are flagged, and every standard error
      is marginal (over all the others, flagged ones included; infinite along a
      direction the data do not determine at all). `True` holds the parameters
      the data do not determine at their start. When the fit ends having
      lowered its loss (a fit that never left its start has nothing to hold)
      with parameters flagged not
      identifiable (see `gauss_newton_uncertainty`), they are set to their
      values in `model` (the optimiser's start where those are outside the
      transform's range) and the others are fitted again, until no further
      parameter is flagged: a flagged parameter is never returned at wherever
      the optimiser drifted along a direction the data do not constrain. The
      data must accept the held values: if the refit's loss exceeds the fit's
      by more than the noise explains (a likelihood-ratio test at level
      `HOLD_TEST_LEVEL` = 1 %, with the fit's noise level), those parameters
      keep their fitted values, flagged, and a note says so. `result.held` marks
      the held ones and the report says so. Holding, not a penalty towards the
      start, leaves the estimates and standard errors of the others those of a
      fit in which the held values are known: their standard errors are
      conditional on the held values and do not include their uncertainty (the
      report says so for each estimate).
    - `misfit_threshold`: after the fit, the residuals are compared with the
      noise (`misfit`): where their mean square exceeds this multiple of the
      noise variance (the declared `Experiment.sigma`, or without it the noise
      the data's own second differences imply), the model does not explain the
      data: `status` is `"misfit"` (not converged), and the report marks the
      standard errors as not meaningful and names the worst channels and times
      (a fit that never left its start stays `"stalled"`).
      Default `MISFIT_THRESHOLD` (4: a residual twice the noise, RMS).
    - `body_names`: names of the bodies in the parameters' names (e.g.
      `stiffness[plate-front].x`, `mass[plate]`; default: their indices,
      `stiffness[0-1].x`, `bodies.mass[0]`) and in the report's initial-state
      entries (default `object, contact1, ...`).

    **Returns:** an `IdentificationResult` (`.model`, `.stderr`, `.loss_history`,
    `.converged`, `.table`, `.held`, `.initial_states`, `.report()`, ...).

    A trial step whose simulation fails (gimbal lock, collapsed link, solver
    failure, NaN, the step budget) is rejected and the step shortened. A
    simulation that fails at the start raises `ValueError`. A fit whose every
    trial step failed ends with `status` `"failed"`, and one whose loss never
    decreased is not `converged`; `reason` says which failures the trials met.
    Where the uncertainty cannot be computed at the estimate (e.g. a parameter
    driven to the end of its range, where $dp/du = 0$), the fit is returned all
    the same, with NaN standard errors and the cause in `uncertainty.reason`
    (and a `RuntimeWarning`).
    """
    start_time = time.perf_counter()
    max_iterations = _iterations(max_iterations, max_steps)
    options, fixed_budget = _simulation_options(
        options, solver, sim_rtol, sim_atol, max_sim_steps, gimbal_tol, link_tol
    )
    experiments = check_experiments(model, experiments)
    names_of_bodies = checked_body_names(body_names, model.n_bodies)
    named = None if body_names is None else names_of_bodies
    free = free_parameters(model, where, transform, mask, named)
    optimizer, method_name = _optimizer(method)
    notes: list[str] = []
    experiments, fit_initial, rest = initial_rule(
        initial, fit_initial, experiments, window, polyorder, notes
    )
    fit_parts = fitted_parts(fit_initial)
    if not isinstance(hold_unidentifiable, bool):
        raise ValueError(
            f"hold_unidentifiable must be True or False, got {hold_unidentifiable!r}"
        )
    value: float
    for name, value in (("xtol", xtol), ("ftol", ftol)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    if not (isinstance(misfit_threshold, int | float) and misfit_threshold > 1):
        raise ValueError(
            f"misfit_threshold must be a number above 1, got {misfit_threshold!r}"
        )
    check_identifiability_thresholds(rcond, max_relative_stderr)
    if feedforward not in FEEDFORWARD_RULES:
        raise ValueError(
            f"feedforward must be one of {FEEDFORWARD_RULES}, got {feedforward!r}"
        )
    if feedforward == "rest":
        if not rest:
            raise ValueError(
                "feedforward='rest' holds the contact bodies in the rest state the "
                "fit recomputes: it needs experiments at rest (Experiment.rest) "
                "and initial 'auto' or 'equilibrium'"
            )
        notes.append(
            "the pose tracking's feedforward of each experiment at rest is the force "
            "that holds its contact bodies in the rest state of the parameters "
            "evaluated (feedforward = rest), not the experiment's numbers"
        )
    if init not in ("equation_error", "model"):
        raise ValueError(f"init must be 'equation_error' or 'model', got {init!r}")
    problem = make_problem(
        model, free, experiments, options, fit_parts, rest, feedforward == "rest"
    )
    no_correction = np.zeros(problem.n_initial)
    start = free.current(model)
    candidates = []  # (label, parameters), evaluated by their simulated loss
    if init == "equation_error":
        try:
            estimated, undetermined = estimate_by_equation_error(
                model,
                experiments,
                where,
                window=window,
                polyorder=polyorder,
                mask=mask,
                rcond=rcond,
                max_relative_stderr=max_relative_stderr,
            )
            guess = free.current(estimated)
        except ValueError as err:  # e.g. too many missing samples to differentiate
            notes.append(f"no equation-error start ({err}); started from the model")
            guess = None
        if guess is not None:
            if np.any(undetermined):
                notes.append(
                    "equation-error estimate not determined by the samples for "
                    + ", ".join(_names(free.names, undetermined))
                    + " (a null direction, or a relative standard error above "
                    + f"{max_relative_stderr:.0%} in the linear fit); took the "
                    "model's values there"
                )
            guess, outside = _within_range(free, guess, start)
            if outside:
                notes.append(
                    "equation-error estimate outside the parameter range for "
                    + ", ".join(outside)
                    + "; took the model's values there"
                )
            guess, beyond = _resolved(free, model, estimated, guess, start, experiments)
            if beyond:
                notes.append(
                    "equation-error estimate beyond what the samples resolve for "
                    + ", ".join(beyond)
                    + " (a natural frequency above "
                    + f"{RESOLUTION:g}x the Nyquist frequency, or a relaxation time "
                    + f"below 1/{RESOLUTION:g} of the sample interval); took the "
                    "model's values there"
                )
            candidates.append(("the equation-error start", guess))
    u_start: np.ndarray | None = None  # the model's values, reparameterised
    try:
        u_start = free.unconstrained(start)
        candidates.append(("the model's values", start))
    except ValueError as err:
        if init == "model":
            raise
        notes.append(f"the model's values are no start ({err})")
    evaluated = []
    u: np.ndarray | jax.Array
    # The starts are simulated under the step budget that a start needing few
    # steps is given (`step_budget(0, max_steps)`); a start that reaches it is
    # simulated again under `max_steps`. The budget is a traced value: the fit's
    # budgets run the program compiled here.
    screening = uncapped = problem
    if not fixed_budget:
        screening = with_step_budget(problem, step_budget(0, options.max_steps))
        uncapped = with_step_budget(problem, options.max_steps)
    start_simulations = 0
    for label, p in candidates:
        u = np.concatenate([free.unconstrained(p), no_correction])
        value, runs, _ = evaluate(jnp.asarray(u), screening)  # inf if failed
        start_simulations += len(experiments)
        over = np.asarray(runs.status) == Status.MAX_STEPS_REACHED
        if screening.max_steps < problem.max_steps and np.any(over):
            value, runs, _ = evaluate(jnp.asarray(u), uncapped)
            start_simulations += len(experiments)
        ok, steps = np.asarray(runs.ok), np.asarray(runs.steps)
        evaluated.append((float(value), label, p, u, ok, steps, runs.status))
    # the equation-error start wins ties (it is listed first; the sort is stable)
    order = sorted(range(len(evaluated)), key=lambda k: evaluated[k][0])
    _, label, initial, u0, ok, steps, status0 = evaluated[order[0]]
    if len(evaluated) > 1:
        notes.append(
            f"started from {label} (loss "
            + " vs ".join(f"{v:.6g} for {name}" for v, name, *_ in evaluated)
            + ")"
        )
    if not np.all(ok):
        _raise_start_failure(problem, ok, np.asarray(status0))
    start_problem = problem

    def fit(problem: FitProblem, u0, budget, refit=False) -> tuple[FitProblem, Trace]:
        # a refit starts next to an optimum: its loss need not decrease
        kwargs: dict[str, Any] = dict(
            xtol=xtol,
            ftol=ftol,
            max_steps=max_iterations,
            progress=progress,
            n_experiments=len(experiments),
            budget=budget,
            expect_decrease=not refit,
        )
        if optimizer is None:
            trace = levenberg_marquardt(problem, u0, **kwargs)
        else:
            trace = optax_minimise(problem, u0, optimizer, **kwargs)
        if budget.raised_to is not None:
            problem = with_step_budget(problem, budget.raised_to)
        if trace.loss_history and trace.jacobian is None:
            r, J = residuals_and_jacobian(jnp.asarray(trace.u), problem)
            trace.residual, trace.jacobian = np.asarray(r), np.asarray(J)
            trace.n_simulations += len(experiments)
        return problem, trace

    def fit_from(u0, steps) -> tuple[FitProblem, Trace, StepBudget]:
        # Trial points that need many more steps than the current point are far
        # off (much stiffer, or lightly damped at high frequency): treat them as
        # failed rather than integrating them to the end.
        budget = StepBudget(adaptive=not fixed_budget, cap=options.max_steps)
        problem = budget.start(start_problem, int(np.max(steps)))
        problem, trace = fit(problem, u0, budget)
        return problem, trace, budget

    problem, trace, budget = fit_from(u0, steps)
    if not trace.loss_history:
        raise ValueError(
            f"the simulation with sensitivities fails at the start, although the "
            f"plain one succeeds (method {method_name}); start from other values "
            f"or pass another solver"
        )
    # A fit that stopped without lowering the loss from the better start (e.g.
    # where the sensitivities of a stiff start are not accurate enough to give a
    # descent direction) is tried again from the other start; the lower end wins.
    # One that ran out of `max_steps` is not: the caller limited the work.
    other_simulations = 0
    _, label2, initial2, u02, ok2, steps2, _ = evaluated[order[-1]]  # (two at most)
    if (
        not _decreased(trace)
        and trace.status != "max_iterations"
        and len(order) > 1
        and np.all(ok2)
    ):
        problem2, trace2, budget2 = fit_from(u02, steps2)
        better = bool(trace2.loss_history) and (
            trace2.loss_history[-1] < trace.loss_history[-1]
        )
        notes.append(
            f"the fit from {label} never lowered its loss ({trace.reason}); fitted "
            f"again from {label2}: loss "
            + (
                f"{trace2.loss_history[0]:.6g} -> {trace2.loss_history[-1]:.6g}"
                if trace2.loss_history
                else "not available (its sensitivities fail)"
            )
            + (", kept" if better else f", not lower: kept the fit from {label}")
        )
        if better:
            other_simulations = trace.n_simulations
            problem, trace, budget = problem2, trace2, budget2
            initial, u0 = initial2, u02
        else:
            other_simulations = trace2.n_simulations
    n_p = free.size
    # Held parameters: at the model's values, or the optimiser's start where those
    # are outside the transform's range.
    u_hold = np.asarray(u0[:n_p] if u_start is None else u_start)
    held = np.zeros(n_p, dtype=bool)
    held_stderr = np.full(n_p, np.nan)
    init_names = initial_state_names(
        problem.order, model.n_bodies, model.convention, fit_initial, names_of_bodies
    )
    settings = (init_names, rcond, max_relative_stderr)
    analysis = _analyse(trace, problem, held, held_stderr, *settings)
    # a fit that never left its start (failed, or no lower loss): nothing drifted,
    # nothing to hold
    rounds = n_p if hold_unidentifiable and _decreased(trace) else 0
    for _ in range(rounds):
        unc = analysis[0]
        newly = ~unc.identifiable & ~held
        if unc.reason or not np.any(newly):
            break
        u_held_start = np.array(trace.u, dtype=np.float64)
        now_held = held | newly
        u_held_start[:n_p] = np.where(now_held, u_hold, u_held_start[:n_p])
        refit_problem, refit = fit(
            with_held(problem, now_held, u_hold),
            jnp.asarray(u_held_start),
            budget,
            refit=True,
        )
        if not refit.loss_history:
            notes.append(
                f"holding {', '.join(_names(free.names, newly))} at their start "
                f"failed to simulate; they keep the fitted values"
            )
            break
        before, after = trace.loss_history[-1], refit.loss_history[-1]
        if not _holding_fits(before, after, int(np.sum(newly)), unc.noise_scale):
            trace.n_simulations += refit.n_simulations
            notes.append(
                f"holding {', '.join(_names(free.names, newly))} at their start "
                f"values raises the loss from {before:.6g} to {after:.6g}, more than "
                f"the noise explains (likelihood-ratio test at {HOLD_TEST_LEVEL:g}): "
                f"the data reject those values, so the parameters keep their fitted "
                f"values (flagged: poorly determined)"
            )
            break
        held_stderr[newly] = unc.stderr[newly]
        held = now_held
        notes.append(
            f"held {', '.join(_names(free.names, newly))} at their start values "
            f"(not identifiable from these experiments) and fitted the others "
            f"again: loss {trace.loss_history[-1]:.6g} -> "
            f"{refit.loss_history[-1]:.6g}"
        )
        problem, trace = refit_problem, _merge(trace, refit)
        analysis = _analyse(trace, problem, held, held_stderr, *settings)
    notes += budget.notes
    if trace.at_bound is not None and np.any(trace.at_bound):
        notes.append(
            f"at the lower end of their range (set there when the linearised fit "
            f"in each alone put it beyond, and that lowered the loss; then held, as "
            f"bounded least squares holds an active bound): "
            f"{', '.join(_names(free.names, trace.at_bound))}; their standard "
            f"errors are those of the linearisation at that end"
        )
    unc, estimate, initial_stderr = analysis
    estimate[held] = (start if u_start is not None else initial)[held]
    dp_du = free.derivative(trace.u)
    flat = [n for n, d, h in zip(free.names, dp_du, held) if not (_live(d) or h)]
    if flat:
        notes.append(
            f"dp/du is 0 or not finite at the estimate of {', '.join(flat)} (the "
            f"parameter reached the end of its range, e.g. 0 for a log-parameter): "
            f"no standard errors in physical units"
        )
    fitted = free_parameters(model, where, "identity", mask, named).apply(
        model, jnp.asarray(estimate)
    )
    by_experiment: list = [None] * len(experiments)
    k = 0
    for y0s, ydot0s in initial_states(jnp.asarray(trace.u), problem):
        for y0, ydot0 in zip(np.asarray(y0s), np.asarray(ydot0s)):
            by_experiment[problem.order[k]] = (y0, ydot0)
            k += 1
    status, reason, misfit = trace.status, trace.reason, None
    if status != "failed":
        _, _, parts = evaluate(jnp.asarray(trace.u), problem)
        n_fitted = int(np.sum(~held)) + problem.n_initial
        misfit = misfit_check(parts, problem, n_fitted, misfit_threshold)
        history = trace.loss_history
        # A stalled fit whose loss fell by less than 0.1 % never left its start
        # and stays "stalled": its residuals are (nearly) those of the start, so
        # they say nothing about whether the model can explain the data.
        left_start = len(history) > 1 and history[-1] < 0.999 * history[0]
        if misfit.misfit and (left_start or status != "stalled"):
            status = "misfit"
            reason = (
                f"the model does not explain the data: "
                f"{misfit.describe(names_of_bodies, model.convention)}; the "
                f"standard errors are not meaningful (the optimiser: {trace.reason})"
            )
    return IdentificationResult(
        model=fitted,
        stderr=free.unflatten(unc.stderr),
        loss_history=np.asarray(trace.loss_history),
        converged=status == "converged",
        status=status,
        reason=reason,
        names=free.names,
        estimate=estimate,
        initial=np.asarray(initial),
        start=np.asarray(start),
        uncertainty=unc,
        n_iterations=trace.n_iterations,
        n_simulations=trace.n_simulations + other_simulations + start_simulations,
        n_rejected=trace.n_rejected,
        n_failed_trials=trace.n_failed_trials,
        method=method_name,
        wall_time=time.perf_counter() - start_time,
        notes=tuple(notes),
        held=held,
        initial_states=tuple(by_experiment),
        initial_state_names=init_names,
        initial_state_estimate=np.asarray(trace.u[n_p:]) + _initial_values(problem),
        initial_state_stderr=initial_stderr,
        misfit=misfit,
    )


def _iterations(max_iterations, max_steps) -> int:
    """The optimiser's iteration limit from `max_iterations`, or from the
    deprecated `max_steps` (with a `DeprecationWarning`); default 100."""
    if max_steps is not None:
        if max_iterations is not None:
            raise ValueError(
                "give max_iterations only (max_steps is its deprecated name)"
            )
        warnings.warn(
            "identify(max_steps=...) is deprecated: the optimiser's limit is "
            "max_iterations (simulate's max_steps counts solver steps)",
            DeprecationWarning,
            stacklevel=3,
        )
        max_iterations = max_steps
    if max_iterations is None:
        return DEFAULT_MAX_ITERATIONS
    if isinstance(max_iterations, bool) or not (
        isinstance(max_iterations, int) and max_iterations >= 1
    ):
        raise ValueError(
            f"max_iterations must be a positive integer, got {max_iterations!r}"
        )
    return max_iterations


def _simulation_options(
    options, solver, sim_rtol, sim_atol, max_sim_steps, gimbal_tol, link_tol
) -> tuple[SimulationOptions, bool]:
    """The fit's `SimulationOptions`, and whether its step budget is fixed (the
    deprecated `max_sim_steps`); the deprecated spellings warn."""
    old = {"sim_rtol": sim_rtol, "sim_atol": sim_atol, "max_sim_steps": max_sim_steps}
    given = [k for k, v in old.items() if v is not None]
    if given:
        warnings.warn(
            f"identify({', '.join(f'{k}=...' for k in given)}) is deprecated: pass "
            f"options=SimulationOptions(rtol=..., atol=..., max_steps=...)",
            DeprecationWarning,
            stacklevel=3,
        )
    if options is not None:
        if not isinstance(options, SimulationOptions):
            raise ValueError(
                f"options must be a SimulationOptions, got {type(options).__name__}"
            )
        clashing = given + [
            name
            for name, value, default in (
                ("solver", solver, None),
                ("gimbal_tol", gimbal_tol, GIMBAL_TOL),
                ("link_tol", link_tol, LINK_TOL),
            )
            if value is not default and value != default
        ]
        if clashing:
            raise ValueError(
                f"give the simulation settings either in options or as "
                f"{', '.join(clashing)}, not both"
            )
        return dataclasses.replace(options, owner="identify"), False
    if max_sim_steps is not None and not (
        isinstance(max_sim_steps, int) and max_sim_steps >= 1
    ):
        raise ValueError(
            f"max_sim_steps must be a positive integer or None, got {max_sim_steps!r}"
        )
    return (
        SimulationOptions(
            solver="tsit5" if solver is None else solver,
            rtol=1e-8 if sim_rtol is None else float(sim_rtol),
            atol=1e-10 if sim_atol is None else float(sim_atol),
            max_steps=START_MAX_STEPS if max_sim_steps is None else max_sim_steps,
            gimbal_tol=float(gimbal_tol),
            link_tol=float(link_tol),
            owner="identify",
        ),
        max_sim_steps is not None,
    )


def _names(names, mask) -> list[str]:
    return [n for n, m in zip(names, mask) if m]


def _live(d) -> bool:
    return bool(np.isfinite(d) and d != 0)


def _initial_values(problem: FitProblem) -> np.ndarray:
    """The experiments' own initial-state entries that the fit estimates (the
    start of the estimates), in the order of $u$."""
    positions, rates = problem.fit_initial
    out = []
    for data in problem.batches:
        y0 = np.asarray(data.experiments.y_init)
        ydot0 = np.asarray(data.experiments.ydot_init)
        for fitted, values in ((positions, y0), (rates, ydot0)):
            if fitted:
                out.append(values.reshape(-1))
    return np.concatenate(out) if out else np.zeros(0)


def _analyse(
    trace: Trace,
    problem: FitProblem,
    held,
    held_stderr,
    initial_names,
    rcond,
    max_relative_stderr,
) -> tuple[Uncertainty, np.ndarray, np.ndarray]:
    """The uncertainty of the parameters at the end of `trace` (of those not held,
    marginal over the estimated initial states, spread over all with
    `with_held_stderr`), the physical estimates, and the standard errors of the
    estimated initial-state entries (marginal over the parameters not held)."""
    free = problem.free
    n_p = free.size
    u = np.asarray(trace.u)
    dp_du = free.derivative(u)
    estimate = np.array(free.physical(jnp.asarray(u[:n_p])))
    J = np.asarray(trace.jacobian)
    with np.errstate(divide="ignore", invalid="ignore"):
        jacobian_p = J[:, :n_p] / dp_du[None, :]
    jacobian_x = J[:, n_p:]
    noise_known = problem.batches[0].experiments.sigma is not None
    keep = ~held
    unc = gauss_newton_uncertainty(
        trace.residual,
        jacobian_p[:, keep],
        estimate[keep],
        noise_known=noise_known,
        rcond=rcond,
        max_relative_stderr=max_relative_stderr,
        names=_names(free.names, keep),
        nuisance=jacobian_x,
    )
    initial_stderr = np.zeros(0)
    if problem.n_initial:
        values = u[n_p:] + _initial_values(problem)
        initial_stderr = gauss_newton_uncertainty(
            trace.residual,
            jacobian_x,
            values,
            noise_known=noise_known,
            rcond=rcond,
            max_relative_stderr=np.inf,
            names=initial_names,
            nuisance=jacobian_p[:, keep],
        ).stderr
    return with_held_stderr(unc, held, held_stderr), estimate, initial_stderr


def _decreased(trace: Trace) -> bool:
    """Whether the fit lowered the loss from its start (an accepted step)."""
    history = trace.loss_history
    return len(history) > 1 and bool(history[-1] < history[0])


def _holding_fits(loss_free, loss_held, n_held: int, noise_scale) -> bool:
    """The likelihood-ratio test of holding `n_held` parameters at given values:
    with the noise level $s$ of the fit (1 where `Experiment.sigma` is given), the
    held fit's loss may exceed the free fit's by at most
    $\\tfrac12 s^2 \\chi^2_{1-\\alpha}(n_{held})$, $\\alpha$ = `HOLD_TEST_LEVEL`
    (under Gaussian noise, $2\\Delta L / s^2 \\sim \\chi^2(n_{held})$ when the held
    values are right)."""
    from scipy.stats import chi2

    s2 = float(noise_scale) ** 2 if np.isfinite(noise_scale) else 0.0
    allowed = 0.5 * s2 * float(chi2.ppf(1.0 - HOLD_TEST_LEVEL, n_held))
    return bool(loss_held - loss_free <= allowed)


def _merge(first: Trace, then: Trace) -> Trace:
    """One trace of a fit and the refit that followed it (counts added, the loss
    history continued, the end of the refit)."""
    then.loss_history = first.loss_history + then.loss_history
    then.grad_norms = first.grad_norms + then.grad_norms
    for name in ("n_iterations", "n_simulations", "n_rejected", "n_failed_trials"):
        setattr(then, name, getattr(first, name) + getattr(then, name))
    then.n_trials += first.n_trials
    then.failures = first.failures + then.failures
    return then


def _optimizer(method):
    if isinstance(method, str):
        if method == "levenberg-marquardt":
            return None, "Levenberg-Marquardt (optimistix, forward-mode Jacobian)"
        if method == "lbfgs":
            return optax.lbfgs(), "L-BFGS (optax, reverse-mode gradient)"
        raise ValueError(
            f"method must be one of {METHODS} or an optax optimiser, got {method!r}"
        )
    if isinstance(method, optax.GradientTransformation):
        return method, "optax optimiser (reverse-mode gradient)"
    raise ValueError(
        f"method must be one of {METHODS} or an optax optimiser, got {method!r}"
    )


def _resolved(free, model, estimated, guess, fallback, experiments):
    """`guess` with the model's values (`fallback`) where the equation-error
    estimate is beyond what the samples resolve (`plausible.unresolved`, at the
    coarsest sample interval of the experiments), and the names of those
    entries."""
    dt = max(float(np.max(np.diff(np.asarray(e.ts)))) for e in experiments)
    flags = unresolved(estimated, dt)
    if flags is None:
        return guess, []
    stiff, damped = flags
    marked = eqx.tree_at(
        lambda m: (m.stiffness, m.damping),
        estimated,
        (jnp.asarray(stiff, jnp.float64), jnp.asarray(damped, jnp.float64)),
    )
    # the flags mean something for the stiffness and damping leaves only
    names = free.names
    bad = np.asarray(free.current(marked)) > 0.5
    bad &= np.array([n.startswith(("stiffness", "damping")) for n in names])
    out = np.where(bad, np.asarray(fallback), np.asarray(guess))
    return out, _names(names, bad)


def _within_range(free, guess, fallback):
    """Entries of `guess` inside each transform's range; others from `fallback`."""
    out, outside, start = np.array(guess, dtype=np.float64), [], 0
    for n, t in zip(free.counts, free.transforms):
        for k in range(start, start + n):
            try:
                t.inverse(np.asarray(out[k : k + 1]), free.names[k])
                ok = np.isfinite(out[k])
            except ValueError:
                ok = False
            if not ok:
                out[k] = fallback[k]
                outside.append(free.names[k])
        start += n
    return out, outside


def _raise_start_failure(problem, ok, status=None):
    bad = [problem.order[k] for k in np.flatnonzero(~ok)]
    how = ""
    if status is not None:
        codes = [Status(int(status[k])) for k in np.flatnonzero(~ok)]
        how = ": " + ", ".join(
            f"experiment {e} stopped with {c.name}"
            + (
                f" (the step limit max_steps = {problem.options.max_steps} of the "
                f"simulation settings)"
                if c == Status.MAX_STEPS_REACHED
                else ""
            )
            for e, c in zip(bad, codes)
        )
    raise ValueError(
        f"the simulation at the starting parameters fails for experiments {bad}"
        f"{how} (stops early: gimbal lock, a collapsed link, the step limit or "
        f"non-finite values; status codes are listed in elasticoop.Status: "
        f"{', '.join(f'{s.value} {s.name}' for s in Status)}); start from other "
        f"values or raise the limit, or pass init='model' with a model that "
        f"simulates"
    )
