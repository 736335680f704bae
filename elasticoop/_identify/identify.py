"""`identify`: fit free model parameters to measured motion (output error)."""

import time
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._options import GIMBAL_TOL, LINK_TOL, SimulationOptions
from .._status import Status
from .equation_error import equation_error
from .experiment import check_experiments
from .optimisers import levenberg_marquardt, optax_minimise
from .parameters import free_parameters
from .residuals import (
    make_problem,
    residuals_and_jacobian,
    residuals_by_experiment,
    with_max_steps,
)
from .result import IdentificationResult
from .step_budget import START_MAX_STEPS, StepBudget
from .uncertainty import gauss_newton_uncertainty

METHODS = ("levenberg-marquardt", "lbfgs")


def identify(
    model,
    experiments,
    where,
    *,
    method="levenberg-marquardt",
    init: str = "equation_error",
    transform="log",
    max_steps: int = 100,
    xtol: float = 1e-8,
    ftol: float = 1e-12,
    progress: bool = True,
    solver: diffrax.AbstractSolver | None = None,
    sim_rtol: float = 1e-8,
    sim_atol: float = 1e-10,
    max_sim_steps: int | None = None,
    gimbal_tol: float = GIMBAL_TOL,
    link_tol: float = LINK_TOL,
    window: int = 21,
    polyorder: int = 4,
    rcond: float = 1e-8,
    max_relative_stderr: float = 0.5,
    mask=None,
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
      (entries outside the transform's range taken from the model) when its
      simulated loss is not above that of the model's values, and from the
      model's values otherwise: with noisy data the differentiated samples can
      spoil the linear estimate, and the start that fits better is kept (a note
      in the result says which).
    - `transform`: reparameterisation of the free leaves: `"log"` (default),
      `"softplus"`, `"identity"`, an `AbstractTransform` such as
      `Bounded(lower, upper)`, or one of these per selected leaf.
    - `max_steps`: the most optimiser steps (Levenberg-Marquardt: trial steps).
    - `xtol`, `ftol`: the fit has converged after an accepted step that changes
      no entry of $u$ by more than `xtol` (for log-parameters: a relative change),
      or lowers the loss by at most `ftol` times the loss; or when a dozen trial
      steps in a row, in an ever smaller trust region, find no lower loss.
    - `progress`: print iteration, loss and gradient norm while fitting.
    - `solver`, `sim_rtol`, `sim_atol`, `max_sim_steps`, `gimbal_tol`, `link_tol`:
      passed to `simulate` (as `solver`, `rtol`, `atol`, `max_steps`, ...).
      `max_sim_steps=None` (default) allows the start's simulations 100 000
      steps and every later one 8x the steps the current point needed (at least
      4096, rounded up to a power of 2, so that fits of similar problems share
      their compiled functions; raised, and the fit's functions compiled anew,
      whenever an accepted point needs more than an eighth of it, up to 100 000):
      a trial point that needs more is far off (much stiffer) and is rejected
      like a failed simulation, instead of costing a long integration. A given
      `max_sim_steps` is the budget of every simulation.
    - `window`, `polyorder`: Savitzky-Golay smoothing of the equation-error start.
    - `rcond`, `max_relative_stderr`: identifiability thresholds (see
      `gauss_newton_uncertainty`).
    - `mask`: fit only some entries of the selected leaves: boolean arrays in the
      structure of `where(model)`, each shaped like its leaf (`None` for a whole
      leaf), e.g. `(k_mask, None)`; the other entries keep the model's values,
      and `stderr` is NaN there. Default: every entry is free.

    **Returns:** an `IdentificationResult` (`.model`, `.stderr`, `.loss_history`,
    `.converged`, `.table`, `.report()`, ...).

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
    experiments = check_experiments(model, experiments)
    free = free_parameters(model, where, transform, mask)
    optimizer, method_name = _optimizer(method)
    value: float
    for name, value in (("max_steps", max_steps),):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    for name, value in (("xtol", xtol), ("ftol", ftol)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    if max_sim_steps is not None and not (
        isinstance(max_sim_steps, int) and max_sim_steps >= 1
    ):
        raise ValueError(
            f"max_sim_steps must be a positive integer or None, got {max_sim_steps!r}"
        )
    if init not in ("equation_error", "model"):
        raise ValueError(f"init must be 'equation_error' or 'model', got {init!r}")
    notes = []
    options = SimulationOptions(
        solver="tsit5" if solver is None else solver,
        rtol=float(sim_rtol),
        atol=float(sim_atol),
        max_steps=START_MAX_STEPS if max_sim_steps is None else max_sim_steps,
        gimbal_tol=float(gimbal_tol),
        link_tol=float(link_tol),
        owner="identify",
    )
    problem = make_problem(model, free, experiments, options)
    start = free.current(model)
    candidates = []  # (label, parameters), evaluated by their simulated loss
    if init == "equation_error":
        try:
            guess = free.current(
                equation_error(
                    model,
                    experiments,
                    where,
                    window=window,
                    polyorder=polyorder,
                    mask=mask,
                )
            )
        except ValueError as err:  # e.g. too many missing samples to differentiate
            notes.append(f"no equation-error start ({err}); started from the model")
            guess = None
        if guess is not None:
            guess, outside = _within_range(free, guess, start)
            if outside:
                notes.append(
                    "equation-error estimate outside the parameter range for "
                    + ", ".join(outside)
                    + "; took the model's values there"
                )
            candidates.append(("the equation-error start", guess))
    try:
        free.unconstrained(start)
        candidates.append(("the model's values", start))
    except ValueError:
        if init == "model":
            raise
    evaluated = []
    u: np.ndarray | jax.Array
    for label, p in candidates:
        u = free.unconstrained(p)
        value, runs = _evaluate(jnp.asarray(u), problem)  # inf if failed
        ok, steps = np.asarray(runs.ok), np.asarray(runs.steps)
        evaluated.append((float(value), label, p, u, ok, steps))
    # the equation-error start wins ties (it is listed first)
    best = min(range(len(evaluated)), key=lambda k: evaluated[k][0])
    _, label, initial, u0, ok, steps = evaluated[best]
    if len(evaluated) > 1:
        notes.append(
            f"started from {label} (loss "
            + " vs ".join(f"{v:.6g} for {name}" for v, name, *_ in evaluated)
            + ")"
        )
    if not np.all(ok):
        _raise_start_failure(problem, ok)
    # Trial points that need many more steps than the current point are far off
    # (much stiffer, or lightly damped at high frequency): treat them as failed
    # rather than integrating them to the end.
    budget = StepBudget(adaptive=max_sim_steps is None)
    problem = budget.start(problem, int(np.max(steps)))
    common: dict[str, Any] = dict(
        xtol=xtol,
        ftol=ftol,
        max_steps=max_steps,
        progress=progress,
        n_experiments=len(experiments),
        budget=budget,
    )
    if optimizer is None:
        trace = levenberg_marquardt(problem, u0, **common)
    else:
        trace = optax_minimise(problem, u0, optimizer, **common)
    notes += budget.notes
    if budget.raised_to is not None:
        problem = with_max_steps(problem, budget.raised_to)
    if not trace.loss_history:
        raise ValueError(
            f"the simulation with sensitivities fails at the start, although the "
            f"plain one succeeds (method {method_name}); start from other values "
            f"or pass another solver"
        )
    if trace.jacobian is None:
        r, J = _residuals_and_jacobian(jnp.asarray(trace.u), problem)
        trace.residual, trace.jacobian = np.asarray(r), np.asarray(J)
        trace.n_simulations += len(experiments)
    u = jnp.asarray(trace.u)
    dp_du = np.asarray(jax.jacfwd(free.physical)(u)).diagonal()
    estimate = np.asarray(free.physical(u))
    flat = [n for n, d in zip(free.names, dp_du) if not (np.isfinite(d) and d != 0)]
    if flat:
        notes.append(
            f"dp/du is 0 or not finite at the estimate of {', '.join(flat)} (the "
            f"parameter reached the end of its range, e.g. 0 for a log-parameter): "
            f"no standard errors in physical units"
        )
    with np.errstate(divide="ignore", invalid="ignore"):
        jacobian_p = trace.jacobian / dp_du[None, :]
    unc = gauss_newton_uncertainty(
        trace.residual,
        jacobian_p,
        estimate,
        noise_known=experiments[0].sigma is not None,
        rcond=rcond,
        max_relative_stderr=max_relative_stderr,
        names=free.names,
    )
    fitted = free.apply(model, u)
    return IdentificationResult(
        model=fitted,
        stderr=free.unflatten(unc.stderr),
        loss_history=np.asarray(trace.loss_history),
        converged=trace.status == "converged",
        status=trace.status,
        reason=trace.reason,
        names=free.names,
        estimate=estimate,
        initial=np.asarray(initial),
        start=np.asarray(start),
        uncertainty=unc,
        n_iterations=trace.n_iterations,
        n_simulations=trace.n_simulations + len(evaluated) * len(experiments),
        n_rejected=trace.n_rejected,
        n_failed_trials=trace.n_failed_trials,
        method=method_name,
        wall_time=time.perf_counter() - start_time,
        notes=tuple(notes),
    )


_residuals_and_jacobian = eqx.filter_jit(residuals_and_jacobian)


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


@eqx.filter_jit
def _evaluate(u, problem):
    """The loss at `u`, and how its simulations went (`Runs`)."""
    parts, runs = residuals_by_experiment(u, problem)
    value = 0.5 * sum(jnp.sum(r**2) for r in parts)
    return value, runs


def _raise_start_failure(problem, ok):
    bad = [problem.order[k] for k in np.flatnonzero(~ok)]
    raise ValueError(
        f"the simulation at the starting parameters fails for experiments {bad} "
        f"(stops early: gimbal lock, a collapsed link, the step limit or non-finite "
        f"values; status codes are listed in elasticoop.Status: "
        f"{', '.join(f'{s.value} {s.name}' for s in Status)}); start from other "
        f"values, or pass init='model' with a model that simulates"
    )
