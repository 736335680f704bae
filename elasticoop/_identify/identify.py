"""`identify`: fit free model parameters to measured motion (output error)."""

import time

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax

from .._simulate import GIMBAL_TOL, LINK_TOL
from .._trajectory import Status
from .equation_error import equation_error
from .experiment import check_experiments
from .optimisers import levenberg_marquardt, optax_minimise
from .parameters import free_parameters
from .residuals import (
    SimulationOptions,
    make_problem,
    residuals_and_jacobian,
    residuals_by_experiment,
)
from .result import IdentificationResult
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
    max_sim_steps: int = 100_000,
    gimbal_tol: float = GIMBAL_TOL,
    link_tol: float = LINK_TOL,
    window: int = 21,
    polyorder: int = 4,
    rcond: float = 1e-8,
    max_relative_stderr: float = 0.5,
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
    - `init`: `"equation_error"` (default: start from `equation_error`, entries
      outside the transform's range kept at the model's values) or `"model"`.
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
    - `window`, `polyorder`: Savitzky-Golay smoothing of the equation-error start.
    - `rcond`, `max_relative_stderr`: identifiability thresholds (see
      `gauss_newton_uncertainty`).

    **Returns:** an `IdentificationResult` (`.model`, `.stderr`, `.loss_history`,
    `.converged`, `.table`, `.report()`, ...).

    A trial step whose simulation fails (gimbal lock, collapsed link, solver
    failure, NaN) is rejected and the step shortened. A simulation that fails at
    the start raises `ValueError`.
    """
    start_time = time.perf_counter()
    experiments = check_experiments(model, experiments)
    free = free_parameters(model, where, transform)
    optimizer, method_name = _optimizer(method)
    for name, value in (("max_steps", max_steps),):
        if not (isinstance(value, int) and value >= 1):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    for name, value in (("xtol", xtol), ("ftol", ftol)):
        if not (np.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a number >= 0, got {value!r}")
    notes = []
    start = free.current(model)
    if init == "equation_error":
        guess = free.current(
            equation_error(
                model, experiments, where, window=window, polyorder=polyorder
            )
        )
        initial, outside = _within_range(free, guess, start)
        if outside:
            notes.append(
                "equation-error start outside the parameter range for "
                + ", ".join(outside)
                + "; started those from the model's values"
            )
    elif init == "model":
        initial = start
    else:
        raise ValueError(f"init must be 'equation_error' or 'model', got {init!r}")
    u0 = free.unconstrained(initial)
    options = SimulationOptions(
        solver=solver,
        rtol=float(sim_rtol),
        atol=float(sim_atol),
        max_steps=int(max_sim_steps),
        gimbal_tol=float(gimbal_tol),
        link_tol=float(link_tol),
    )
    problem = make_problem(model, free, experiments, options)
    common = dict(
        xtol=xtol,
        ftol=ftol,
        max_steps=max_steps,
        progress=progress,
        n_experiments=len(experiments),
    )
    if optimizer is None:
        trace = levenberg_marquardt(problem, u0, **common)
    else:
        trace = optax_minimise(problem, u0, optimizer, **common)
    if not trace.loss_history:
        _raise_start_failure(problem, u0, experiments)
    if trace.jacobian is None:
        r, J = _residuals_and_jacobian(jnp.asarray(trace.u), problem)
        trace.residual, trace.jacobian = np.asarray(r), np.asarray(J)
        trace.n_simulations += len(experiments)
    u = jnp.asarray(trace.u)
    dp_du = np.asarray(jax.jacfwd(free.physical)(u)).diagonal()
    estimate = np.asarray(free.physical(u))
    unc = gauss_newton_uncertainty(
        trace.residual,
        trace.jacobian / dp_du[None, :],
        estimate,
        noise_known=experiments[0].sigma is not None,
        rcond=rcond,
        max_relative_stderr=max_relative_stderr,
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
        n_simulations=trace.n_simulations,
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
    for shape, t in zip(free.shapes, free.transforms):
        n = int(np.prod(shape))
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
def _start_status(u, problem):
    return residuals_by_experiment(u, problem)[1]


def _raise_start_failure(problem, u0, experiments):
    ok = np.asarray(_start_status(jnp.asarray(u0), problem))
    bad = [problem.order[k] for k in np.flatnonzero(~ok)]
    raise ValueError(
        f"the simulation at the starting parameters fails for experiments {bad} "
        f"(stops early: gimbal lock, a collapsed link, the step limit or non-finite "
        f"values; status codes are listed in elasticoop.Status: "
        f"{', '.join(f'{s.value} {s.name}' for s in Status)}); start from other "
        f"values, or pass init='model' with a model that simulates"
    )
