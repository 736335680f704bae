"""The two routes to the output-error optimum, each driven step by step from Python
(so that progress is shown and every step is recorded):

- `levenberg_marquardt`: Levenberg-Marquardt on the residual vector, assembled as
  `optimistix.LevenbergMarquardt` is (its public parts: the trust region
  `optimistix.ClassicalTrustRegion` and the damped Gauss-Newton step
  `optimistix.DampedNewtonDescent`, solved by QR), with the Jacobian from
  forward-mode sensitivities (one integration carrying one tangent per parameter,
  `diffrax.ForwardMode`). Each step's accepted loss, gradient, acceptance and
  trial loss are explicit outputs of the step; its simulations (`evaluate`,
  `jacobian`) and the trust region's update (`_lm_update`) are compiled
  separately, each once per fit (`evaluate` once per step budget). A trial step
  whose loss is not lower (an infinite loss for a failed simulation) is rejected
  by the trust region, which shrinks the step; such a trial costs one plain
  simulation, as its Jacobian is not computed.
- `optax_minimise`: any optax optimiser on $\\tfrac12\\sum r^2$ with reverse-mode
  gradients through `simulate` (diffrax's `RecursiveCheckpointAdjoint`); the
  default `optax.lbfgs()` uses a zoom line search, which treats an infinite or NaN
  loss as outside the domain and shortens the step. For optimisers without a line
  search (e.g. `optax.adam`) a step to a non-finite loss is halved until it is
  finite.
"""

import collections
import dataclasses
import time
from typing import Any, TypeAlias

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optax
import optimistix as optx

from .._status import Status
from .parameters import FreeParameters
from .residuals import (
    FitProblem,
    Runs,
    evaluate,
    loss,
    loss_and_runs,
    residuals_by_experiment,
    residuals_jacobian_and_runs,
    with_held,
    with_jacobian_loss_limit,
    with_scaling,
    with_static_budget,
)
from .step_budget import StepBudget

# Marquardt's initial damping: lambda_0 = TAU * max diag(J^T J) at the start.
TAU = 1e-3
# Consecutive rejected trial steps (each shrinks the trust region 4x) after which
# no lower loss exists within numerical resolution: the minimum is found.
MAX_REJECTIONS = 12
# A parameter found at the lower end of its range (see `_at_bound`) is set to this
# fraction of its distance from that end: its effect on the residuals is then this
# fraction of what it was, zero to the accuracy of any simulation.
BOUND_FRACTION = 1e-12
# The statistical stop: the iteration has converged where the full Gauss-Newton
# step from the accepted point would move the parameters by at most this many
# standard errors (in the metric of their covariance, along any direction), i.e.
# would lower the loss by at most STAT_STEP**2 / 2 units of the noise variance.
STAT_STEP = 0.1
# Halvings of an optax update whose loss is not finite before giving up.
MAX_HALVINGS = 30
# A plain optimiser (no line search) takes steps set by its learning rate, so a
# small step is no sign of an optimum by itself: it has converged only where, in
# addition, no entry of the loss's gradient in u exceeds this fraction of the loss
# at the start (for log-parameters: a 1 % change of any parameter changes the loss
# by at most 1e-8 of the start's, to first order; the start's loss, not the
# current one, which falls to zero at an exact fit faster than the gradient).
PLAIN_GTOL = 1e-6


@dataclasses.dataclass
class Trace:
    """What happened during a fit."""

    u: np.ndarray
    loss_history: list = dataclasses.field(default_factory=list)
    grad_norms: list = dataclasses.field(default_factory=list)
    n_iterations: int = 0
    n_simulations: int = 0
    n_rejected: int = 0
    n_failed_trials: int = 0
    n_trials: int = 0  # points evaluated after the start
    # why trial simulations failed: description -> number of trials
    failures: collections.Counter = dataclasses.field(
        default_factory=collections.Counter
    )
    status: str = "max_iterations"
    reason: str = ""
    wall_time: float = 0.0
    residual: np.ndarray | None = None  # at the optimum, when the method has them
    jacobian: np.ndarray | None = None  # d residual / d u at the optimum
    # per free parameter: set at the lower end of its range (`_at_bound`)
    at_bound: np.ndarray | None = None


class _Progress:
    def __init__(self, enabled: bool, method: str):
        self.enabled = enabled
        if enabled:
            print(f"identify ({method}): iter  loss          |grad|        note")

    def __call__(self, iteration, value, grad_norm, note=""):
        if self.enabled:
            print(
                f"{'':>20}{iteration:5d}  {value:12.6e}  {grad_norm:12.6e}  {note}",
                flush=True,
            )


# `optx.FunctionInfo.ResidualJac` is a class attribute, which a type checker does not
# accept as a type: annotate with this alias instead.
_ResidualJac: TypeAlias = Any


class _LMState(eqx.Module):
    """The state of the Levenberg-Marquardt iteration, in the solver's variables
    $v$: the last accepted point and the residuals and Jacobian there, the next
    trial point, and the states of the trust region and of the descent (passed
    through unread)."""

    first_step: jax.Array
    y: jax.Array
    y_eval: jax.Array
    f_info: _ResidualJac
    search_state: Any
    descent_state: Any


def _lm_parts():
    """The trust region and the damped Gauss-Newton descent that make up
    `optimistix.LevenbergMarquardt` (with its default QR solve)."""
    return optx.ClassicalTrustRegion(), optx.DampedNewtonDescent(linear_solver=lx.QR())


def _f_info(v, problem) -> tuple[_ResidualJac, Runs]:
    """Residuals and forward-mode Jacobian with respect to $v$, where
    $u = $ `u_offset + u_scale * v`, and how the simulations went."""
    u = problem.u_offset + problem.u_scale * v
    r, J, runs = residuals_jacobian_and_runs(u, problem)
    J = lx.MatrixLinearOperator(J * problem.u_scale[None, :])
    return optx.FunctionInfo.ResidualJac(r, J), runs


@eqx.filter_jit
def _lm_init(search, descent, v, n_residuals: int) -> _LMState:
    r = jax.ShapeDtypeStruct((n_residuals,), jnp.float64)
    f_info = optx.FunctionInfo.ResidualJac(
        jnp.zeros(r.shape, r.dtype),
        lx.MatrixLinearOperator(jnp.zeros(r.shape + v.shape, r.dtype)),
    )
    f_info_struct = eqx.filter_eval_shape(lambda: f_info)
    return _LMState(
        first_step=jnp.array(True),
        y=v,
        y_eval=v,
        f_info=f_info,
        search_state=search.init(v, f_info_struct),
        descent_state=descent.init(v, f_info_struct),
    )


def _lm_step(search, descent, state: _LMState, problem):
    """Simulate at the trial point, let the trust region accept or reject it, and
    propose the next trial point. Returns the new state, the loss and its gradient
    at the (new) accepted point, whether the trial was accepted, the loss at the
    trial point ($+\\infty$ where a simulation failed), the result code and how
    the trial's simulations went (`Runs`).

    The simulations are compiled programs of their own (`evaluate` and
    `jacobian`), shared with the rest of the fit; the trust region's update is a
    small one (`_lm_update`)."""
    # Trial points with a higher loss than the accepted one are rejected anyway:
    # skip their Jacobians (the first evaluation always computes it).
    limit = (
        problem.jacobian_loss_limit if bool(state.first_step) else state.f_info.as_min()
    )
    f_eval_info, runs = _f_info(state.y_eval, with_jacobian_loss_limit(problem, limit))
    return (*_lm_update(search, descent, state, f_eval_info), runs)


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (get_num_traces)
def _lm_update(search, descent, state: _LMState, f_eval_info):
    """The trust region's accept or reject of the trial point evaluated as
    `f_eval_info`, and the next trial point (see `_lm_step`)."""
    step_size, accept, search_result, search_state = search.step(
        state.first_step,
        state.y,
        state.y_eval,
        state.f_info,
        f_eval_info,
        state.search_state,
    )
    y, f_info, descent_state = jax.lax.cond(
        accept,
        lambda: (
            state.y_eval,
            f_eval_info,
            descent.query(state.y_eval, f_eval_info, state.descent_state),
        ),
        lambda: (state.y, state.f_info, state.descent_state),
    )
    y_diff, descent_result = descent.step(step_size, descent_state)
    result = optx.RESULTS.where(
        search_result == optx.RESULTS.successful, descent_result, search_result
    )
    state = _LMState(
        first_step=jnp.array(False),
        y=y,
        y_eval=y + y_diff,
        f_info=f_info,
        search_state=search_state,
        descent_state=descent_state,
    )
    value, grad = f_info.as_min(), f_info.compute_grad()
    return state, value, grad, accept, f_eval_info.as_min(), result


def _lm_final(state: _LMState):
    """Residuals and Jacobian (with respect to $v$) at the accepted point."""
    return np.asarray(state.f_info.residual), np.asarray(state.f_info.jac.as_matrix())


def _small_step(u, u_new, value, value_new, xtol, ftol) -> bool:
    """An accepted step is the last when it moves $u$ by at most `xtol` (largest
    entry; a relative change for log-parameters) or lowers the loss by at most
    `ftol` times the loss."""
    du = float(np.max(np.abs(np.asarray(u_new) - np.asarray(u))))
    return bool(du <= xtol or (value - value_new) <= ftol * abs(value))


def _record_failure(trace: Trace, runs: Runs, problem: FitProblem) -> None:
    """Count a trial whose simulations failed, by why they failed."""
    trace.n_failed_trials += 1
    why = set()
    for ok, status in zip(np.asarray(runs.ok), np.asarray(runs.status)):
        if ok:
            continue
        if status == Status.MAX_STEPS_REACHED:
            why.add(f"reached the step budget of {problem.max_steps} solver steps")
        elif status == Status.SUCCESS:
            why.add("gave non-finite values")
        else:
            why.add(f"stopped with status {Status(int(status)).name}")
    trace.failures.update(why or {"gave a non-finite loss"})


def _conclude(trace: Trace, expect_decrease: bool = True) -> Trace:
    """Make `status` and `reason` say what the trials met and whether the loss
    decreased: a fit whose every trial failed has `status` `"failed"`, and one whose
    loss never decreased is not `"converged"` (`"stalled"`) unless
    `expect_decrease` is false (a fit that starts at an optimum)."""
    reasons = [trace.reason] if trace.reason else []
    failures = ", ".join(f"{n} {why}" for why, n in trace.failures.most_common())
    decreased = (
        len(trace.loss_history) > 1 and trace.loss_history[-1] < trace.loss_history[0]
    )
    if trace.n_trials and trace.n_failed_trials == trace.n_trials:
        trace.status = "failed"
        reasons.insert(
            0,
            f"every trial step ({trace.n_trials}) failed to simulate ({failures}); "
            f"the loss never moved from the start",
        )
    else:
        if trace.n_failed_trials:
            reasons.append(
                f"{trace.n_failed_trials} of {trace.n_trials} trial steps failed to "
                f"simulate ({failures})"
            )
        if not decreased and trace.loss_history and expect_decrease:
            if trace.status == "converged":
                trace.status = "stalled"
            reasons.append("no step lowered the loss from the start")
    trace.reason = "; ".join(reasons)
    return trace


def _at_bound(free: FreeParameters, held, u, r, J_u) -> np.ndarray:
    """The free parameters (not `held`) that a bounded least-squares step puts at
    the lower end $l$ of their range: where the residuals' linearisation in that
    physical parameter alone, $r + J_{p,k} (p_k' - p_k)$, is least at
    $p_k' \\le l$, i.e. $g_k = J_{p,k}^T r > 0$ and
    $g_k \\ge |J_{p,k}|^2 (p_k - l)$, with $J_{p,k} = J_{u,k} / (dp_k/du_k)$ (for
    $p = e^u$: $J_{u,k}^T r \\ge |J_{u,k}|^2$). In $u$ the end of the range is
    infinitely far: without this test such a parameter drifts towards it by a
    bounded step per iteration, and the fit crawls."""
    n_p = free.size
    lower = free.lower_bounds()
    uu = jnp.asarray(np.asarray(u)[:n_p])
    p = np.asarray(free.physical(uu))
    dp_du = free.derivative(uu)
    J = np.asarray(J_u)[:, :n_p]
    g = J.T @ np.asarray(r)
    c = np.sum(J**2, axis=0)
    with np.errstate(invalid="ignore", divide="ignore"):
        reach = c * (p - lower) / dp_du
        out = (g > 0) & (g >= reach) & (dp_du > 0)
    # one that has drifted to the end already (p = l to machine precision)
    out = (out | ~(p > lower)) & np.isfinite(lower)
    return out & ~np.asarray(held, dtype=bool)


def _to_bound(free: FreeParameters, u, mask, u_start) -> np.ndarray:
    """`u` with the parameters of `mask` set to `BOUND_FRACTION` of the distance
    of their start (`u_start`) from the lower end of their range."""
    n_p = free.size
    u = np.array(u, dtype=np.float64)
    p0 = np.asarray(free.physical(jnp.asarray(np.asarray(u_start)[:n_p])))
    lower = free.lower_bounds()
    near = lower + BOUND_FRACTION * (p0 - lower)
    # invert only the entries of `mask` (the others at a value inside the range)
    inside = np.asarray(free.physical(jnp.zeros(n_p)))
    u[:n_p] = np.where(mask, free.unconstrained(np.where(mask, near, inside)), u[:n_p])
    return u


def _gauss_newton_gain(r, J) -> float:
    """$\\tfrac12(|r|^2 - |r + J\\delta|^2)$ for the Gauss-Newton step
    $\\delta = -J^+ r$ (least squares, directions of $J$ below 1e-12 of its
    largest singular value left out): the decrease of the loss its linearisation
    predicts. With residuals in units of the noise, $2\\times$ it is
    $\\delta^T J^T J \\delta$, the squared length of the step in the metric of the
    parameters' inverse covariance (in standard errors)."""
    r, J = np.asarray(r), np.asarray(J)
    U, sv, _ = np.linalg.svd(J, full_matrices=False)
    keep = sv > 1e-12 * (sv[0] if sv.size else 0.0)
    return float(0.5 * np.sum((U[:, keep].T @ r) ** 2))


def levenberg_marquardt(
    problem: FitProblem,
    u0,
    *,
    xtol,
    ftol,
    max_steps,
    progress,
    n_experiments,
    budget: StepBudget,
    expect_decrease: bool = True,
) -> Trace:
    """Minimise $\\tfrac12|r(u)|^2$ by Levenberg-Marquardt (optimistix).

    Every solver step simulates all experiments once (with sensitivities) at a
    trial point; a trial that does not lower the loss is rejected. After every
    accepted step the simulations' step budget follows the new point (`budget`).
    `expect_decrease=False`: a start at an optimum, whose loss need not fall, is
    no stall (see `_conclude`).

    Parameters at the end of their range: once the iteration has slowed (an
    accepted step lowering the loss by less than $L / (N - n)$, one unit of
    $\\chi^2$ at the noise level the loss implies), the parameters that a bounded
    least-squares step would put at the lower end of their range (`_at_bound`:
    e.g. a damping the data would rather have negative) are tried there, all at
    once (`BOUND_FRACTION` of their distance from it; one simulation). Where that
    lowers the loss they are held there, as a bounded least-squares method holds
    its active bounds (`Trace.at_bound`), and the iteration goes on with the
    others from there, its trust region as it was. In the log-parameters $u$ of
    the fit the end of the range is infinitely far away: without this such a
    parameter drifts towards it by a bounded step per iteration, and the fit
    crawls without converging."""
    start = time.perf_counter()
    # The convergence test is ours (`_small_step`), not optimistix's Cauchy test.
    search, descent = _lm_parts()
    u = jnp.asarray(u0)
    trace = Trace(u=np.asarray(u))
    # optimistix damps with lambda I, lambda = 1 at the start. Solve instead for
    # v = (u - u0) * |J0 e_k| (unit Jacobian columns at the start, as MINPACK
    # scales), and multiply the residuals by c so that lambda = 1 is Marquardt's
    # lambda_0 = TAU max diag(J^T J). One extra evaluation at u0; the scalings are
    # traced values, so nothing recompiles.
    state = _lm_init(search, descent, u, problem.n_residuals)
    state, value, *_ = _lm_step(search, descent, state, problem)
    trace.n_simulations += n_experiments
    if not np.isfinite(float(value)):
        trace.wall_time = time.perf_counter() - start
        return trace  # the start failed: `identify` reports it
    _, J0 = _lm_final(state)
    norms = np.sqrt(np.sum(J0**2, axis=0))
    live = norms > 1e-12 * max(float(np.max(norms)), 1e-300)
    u_scale = np.where(live, 1.0 / np.where(live, norms, 1.0), 1.0)
    scale = 1.0 / np.sqrt(TAU)
    problem = with_scaling(problem, scale, u, u_scale)
    u0_arr = u
    state = _lm_init(search, descent, jnp.zeros_like(u), problem.n_residuals)
    show = _Progress(progress, "Levenberg-Marquardt, forward-mode Jacobian")
    # Rejected trials in a row whose simulations succeeded: failed ones (a trial
    # point far off) say nothing about the minimum, only that the step was long.
    # Likewise, after a failed trial the accepted steps are small because the
    # failures shrank the trust region: they are no test of convergence until a
    # trial is again rejected for its loss (the region is bounded by the loss).
    rejected_in_row = 0
    shrunk_by_failures = False
    n_p = problem.free.size
    at_bound = np.zeros(n_p, dtype=bool)
    snapped = False  # the last accepted point is the one set at bounds
    n_residuals, n_live = int(J0.shape[0]), int(np.sum(live))
    for _ in range(max_steps):
        u_prev = u
        first = trace.n_iterations == 0
        state, value, gnorm, accepted, trial_loss, result, runs = _lm_step(
            search, descent, state, problem
        )
        u = u0_arr + u_scale * state.y
        u = u.at[:n_p].set(jnp.where(problem.held, problem.u_held, u[:n_p]))
        trace.n_simulations += n_experiments
        trace.n_trials += not first
        value = float(value) / scale**2
        gnorm = float(np.linalg.norm(np.asarray(gnorm) / u_scale)) / scale**2
        if bool(accepted):
            rejected_in_row = 0
            trace.n_iterations += 1
            trace.loss_history.append(value)
            trace.grad_norms.append(gnorm)
            show(trace.n_iterations, value, gnorm)
            problem = budget.follow(
                problem, int(np.max(np.asarray(runs.steps))), trace.n_iterations
            )
            last = trace.loss_history[-2] if len(trace.loss_history) > 1 else None
            tested = last is not None and not shrunk_by_failures and not snapped
            snapped = False
            slowed = last is not None and last - value < value / max(
                n_residuals - n_live, 1
            )
            if slowed or tested:
                r, Jv = _lm_final(state)
            if slowed:
                mask = _at_bound(
                    problem.free,
                    problem.held,
                    np.asarray(u),
                    r / scale,
                    Jv / scale / u_scale[None, :],
                )
                if np.any(mask):
                    u_try = _to_bound(
                        problem.free, np.asarray(u), mask, np.asarray(u0_arr)
                    )
                    trial = with_held(
                        problem,
                        np.asarray(problem.held) | mask,
                        np.where(mask, u_try[:n_p], np.asarray(problem.u_held)),
                    )
                    trace.n_simulations += n_experiments
                    trace.n_trials += 1
                    tried, _, _ = evaluate(jnp.asarray(u_try), trial)
                    if float(tried) / scale**2 < value:
                        # re-evaluate there (an accepted first step keeps the
                        # trust region); its Jacobian has no columns for them
                        at_bound |= mask
                        problem = trial
                        state = eqx.tree_at(
                            lambda s: (s.first_step, s.y_eval),
                            state,
                            (jnp.array(True), state.y),
                        )
                        snapped = True
                        names = [n for n, m in zip(problem.free.names, mask) if m]
                        show(
                            trace.n_iterations,
                            value,
                            gnorm,
                            "to bounds: " + ", ".join(names),
                        )
                        continue
            if tested:
                s2 = 2.0 * value / max(n_residuals - n_live, 1)
                gain = _gauss_newton_gain(r / scale, Jv / scale)
                if gain <= 0.5 * STAT_STEP**2 * s2:
                    trace.status = "converged"
                    trace.reason = (
                        f"statistical stop: the Gauss-Newton step would lower the "
                        f"loss by {gain:.3g}, a move of at most {STAT_STEP:g} "
                        f"standard errors"
                    )
                    break
            if tested and _small_step(u_prev, u, last, value, xtol, ftol):
                trace.status = "converged"
                trace.reason = f"last step below xtol = {xtol} or ftol = {ftol}"
                break
        else:
            trace.n_rejected += 1
            if np.isfinite(float(trial_loss)):
                rejected_in_row += 1
                shrunk_by_failures = False
            else:
                shrunk_by_failures = True
                _record_failure(trace, runs, problem)
                show(trace.n_iterations, value, gnorm, "trial failed")
        if result != optx.RESULTS.successful:
            trace.status = "failed"
            trace.reason = str(optx.RESULTS[result])  # type: ignore[misc]
            break
        if rejected_in_row >= MAX_REJECTIONS:
            trace.status = "converged"
            trace.reason = (
                f"no lower loss within a trust region shrunk {MAX_REJECTIONS} times "
                f"(minimum resolved to the accuracy of the simulations)"
            )
            break
    else:
        trace.reason = f"reached max_iterations = {max_steps} iterations"
    r, Jv = _lm_final(state)
    trace.residual = r / scale
    trace.jacobian = Jv / scale / u_scale[None, :]
    trace.u = np.asarray(u)
    trace.at_bound = at_bound
    if np.any(at_bound):
        # held here, they have no Jacobian columns: the caller computes the
        # Jacobian at the end with them free
        trace.jacobian = None
        trace.reason = "; ".join(
            x
            for x in (
                trace.reason,
                f"{int(np.sum(at_bound))} "
                + (
                    "parameter set at the lower end of its range"
                    if int(np.sum(at_bound)) == 1
                    else "parameters set at the lower end of their range"
                )
                + " (at_bound)",
            )
            if x
        )
    trace.wall_time = time.perf_counter() - start
    return _conclude(trace, expect_decrease)


# optax's updates mix integer step counts with floats (e.g. Adam's bias correction
# `decay**count`): trace them under standard dtype promotion, so that a user (or a
# test suite) running with `jax_numpy_dtype_promotion="strict"` can still fit.
def _optax_promotion():
    return jax.numpy_dtype_promotion("standard")


@eqx.filter_jit
def _value_and_grad(u, problem):
    """The loss, its gradient and how the simulations went."""
    (value, runs), grad = jax.value_and_grad(loss_and_runs, has_aux=True)(u, problem)
    return value, grad, runs


@eqx.filter_jit
def _runs_at(u, problem) -> Runs:
    """How the simulations at `u` go (no derivatives)."""
    return residuals_by_experiment(u, problem)[1]


@eqx.filter_jit
def _linesearch_step(optimizer, u, state, problem):
    """One update of a line-search optimiser (e.g. `optax.lbfgs`), reusing the value
    and gradient its line search stored at `u`."""

    def fun(v):
        return loss(v, problem)

    value, grad = optax.value_and_grad_from_state(fun)(u, state=state)
    with _optax_promotion():
        updates, state = optimizer.update(
            grad, state, u, value=value, grad=grad, value_fn=fun
        )
    steps = optax.tree.get(state, "num_linesearch_steps")
    return optax.apply_updates(u, updates), state, value, grad, steps


@eqx.filter_jit
def _plain_update(optimizer, u, state, grad):
    with _optax_promotion():
        updates, state = optimizer.update(grad, state, u)
    return updates, state


def optax_minimise(
    problem: FitProblem,
    u0,
    optimizer,
    *,
    xtol,
    ftol,
    max_steps,
    progress,
    n_experiments,
    budget: StepBudget,
    expect_decrease: bool = True,
) -> Trace:
    """Minimise $\\tfrac12|r(u)|^2$ with an optax optimiser and reverse-mode
    gradients, until a step is small (`_small_step`) without raising the loss.
    After every step the simulations' step budget follows the new point (`budget`;
    with a line search this costs one simulation without derivatives there)."""
    start = time.perf_counter()
    u = jnp.asarray(u0)
    trace = Trace(u=np.asarray(u))
    show = _Progress(progress, f"optax {getattr(optimizer, '__name__', '')}".strip())
    # optax initialises some scalars weakly typed and updates them strongly
    # typed; fix their types now so that the step compiles once.
    state = jax.tree.map(
        lambda x: jnp.asarray(x, x.dtype) if eqx.is_array(x) else x,
        optimizer.init(u),
    )
    linesearch = optax.tree.get(state, "value") is not None
    # (the gradients' simulations under the budget as a static setting)
    gradients = with_static_budget(problem)
    if not linesearch:
        value, grad, _ = _value_and_grad(u, gradients)
        trace.n_simulations += n_experiments
    for _ in range(max_steps):
        halved = False
        if linesearch:
            u_new, state, value, grad, steps = _linesearch_step(
                optimizer, u, state, gradients
            )
            # the first call also evaluates the loss at u0
            trace.n_simulations += n_experiments * (
                int(steps) + (trace.n_iterations == 0)
            )
            trace.n_trials += int(steps)
            if trace.n_iterations == 0 and not np.isfinite(float(value)):
                break  # the start failed: `identify` reports it
            value_new = float(optax.tree.get(state, "value"))
            if not np.isfinite(value_new):
                trace.status = "stalled"
                trace.reason = "the line search found no finite lower loss"
                break
            if budget.adaptive:
                runs = _runs_at(u_new, problem)
                trace.n_simulations += n_experiments
        else:
            if not np.isfinite(float(value)):
                break  # the start failed: `identify` reports it
            updates, state = _plain_update(optimizer, u, state, grad)
            for _halving in range(MAX_HALVINGS):
                u_new = u + updates
                value_new, grad_new, runs = _value_and_grad(u_new, gradients)
                trace.n_simulations += n_experiments
                trace.n_trials += 1
                if np.isfinite(float(value_new)):
                    break
                trace.n_rejected += 1
                _record_failure(trace, runs, problem)
                halved = True
                updates = 0.5 * updates
                show(trace.n_iterations, float(value), 0.0, "trial failed, halved")
            else:
                trace.status = "stalled"
                trace.reason = "no finite loss along the update direction"
                break
        if trace.n_iterations == 0:
            trace.loss_history.append(float(value))
        if linesearch and float(value_new) > float(value):
            trace.status = "stalled"
            trace.reason = "the line search found no lower loss"
            break
        trace.n_iterations += 1
        gnorm = float(jnp.linalg.norm(grad))
        trace.loss_history.append(float(value_new))
        trace.grad_norms.append(gnorm)
        show(trace.n_iterations, float(value_new), gnorm)
        if budget.adaptive:
            steps_new = int(np.max(np.asarray(runs.steps)))
            problem = budget.follow(problem, steps_new, trace.n_iterations)
            gradients = with_static_budget(problem)
        # a step that raised the loss, or one halved because the full one failed,
        # is no sign of convergence: a plain optimiser (no line search) goes on
        done = (
            float(value_new) <= float(value)
            and not halved
            and _small_step(u, u_new, float(value), float(value_new), xtol, ftol)
        )
        u = u_new
        if not linesearch:
            value, grad = value_new, grad_new
        if done and not linesearch:
            slope = float(np.max(np.abs(np.asarray(grad)))) / max(
                abs(trace.loss_history[0]), np.finfo(float).tiny
            )
            if slope > PLAIN_GTOL:
                trace.status = "stalled"
                trace.reason = (
                    f"the last step was below xtol = {xtol} or ftol = {ftol}, but the "
                    f"gradient is not small (its largest entry is {slope:.3g} times "
                    f"the loss at the start, above {PLAIN_GTOL:g}): the optimiser's "
                    f"steps are set by its learning rate; raise it, or use the "
                    f"default method"
                )
                break
        if done:
            trace.status = "converged"
            trace.reason = f"last step below xtol = {xtol} or ftol = {ftol}"
            break
    else:
        trace.reason = f"reached max_iterations = {max_steps} iterations"
    trace.u = np.asarray(u)
    trace.wall_time = time.perf_counter() - start
    return _conclude(trace, expect_decrease)
