"""The two routes to the output-error optimum, each driven step by step from Python
(so that progress is shown and every step is recorded):

- `levenberg_marquardt`: `optimistix.LevenbergMarquardt` on the residual vector,
  with the Jacobian from forward-mode sensitivities (one integration carrying one
  tangent per parameter, `diffrax.ForwardMode`). A trial step whose loss is not
  lower (an infinite loss for a failed simulation) is rejected by the trust region,
  which shrinks the step; such a trial costs one plain simulation, as its
  Jacobian is not computed.
- `optax_minimise`: any optax optimiser on $\\tfrac12\\sum r^2$ with reverse-mode
  gradients through `simulate` (diffrax's `RecursiveCheckpointAdjoint`); the
  default `optax.lbfgs()` uses a zoom line search, which treats an infinite or NaN
  loss as outside the domain and shortens the step. For optimisers without a line
  search (e.g. `optax.adam`) a step to a non-finite loss is halved until it is
  finite.
"""

import dataclasses
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx

from .residuals import (
    Problem,
    loss,
    residuals_fwd,
    with_jacobian_loss_limit,
    with_scaling,
)

# Marquardt's initial damping: lambda_0 = TAU * max diag(J^T J) at the start.
TAU = 1e-3
# Consecutive rejected trial steps (each shrinks the trust region 4x) after which
# no lower loss exists within numerical resolution: the minimum is found.
MAX_REJECTIONS = 12
# Halvings of an optax update whose loss is not finite before giving up.
MAX_HALVINGS = 30


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
    status: str = "max_steps"
    reason: str = ""
    wall_time: float = 0.0
    residual: np.ndarray | None = None  # at the optimum, when the method has them
    jacobian: np.ndarray | None = None  # d residual / d u at the optimum


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


def _fn(v, problem):
    u = problem.u_offset + problem.u_scale * v
    return residuals_fwd(u, problem=problem), None


class _TrialRecord:
    """Receives the loss of each trial point from the solver's `verbose` hook."""

    loss = 0.0

    def set(self, value):
        self.loss = float(value)


_TRIAL = _TrialRecord()


def _record_trial(**fields):
    # optimistix calls `verbose` with (name, value) pairs; keep the trial's loss
    jax.debug.callback(_TRIAL.set, fields["loss_this_step"][1], ordered=True)


@eqx.filter_jit
def _lm_init(solver, u, problem):
    f_struct = jax.eval_shape(lambda: _fn(u, problem)[0])
    return solver.init(_fn, u, problem, {}, f_struct, None, frozenset())


@eqx.filter_jit
def _lm_step(solver, u, state, problem):
    u_new, state, _ = solver.step(_fn, u, problem, {}, state, frozenset())
    done, result = solver.terminate(_fn, u_new, problem, {}, state, frozenset())
    info = state.f_info
    value = 0.5 * jnp.sum(info.residual**2)
    grad = info.jac.transpose().mv(info.residual)
    accepted = state.num_steps_since_acceptance == 0
    return u_new, state, value, grad, accepted, done, result


@eqx.filter_jit
def _lm_final(state):
    return state.f_info.residual, state.f_info.jac.as_matrix()


def _small_step(u, u_new, value, value_new, xtol, ftol) -> bool:
    """An accepted step is the last when it moves $u$ by at most `xtol` (largest
    entry; a relative change for log-parameters) or lowers the loss by at most
    `ftol` times the loss."""
    du = float(np.max(np.abs(np.asarray(u_new) - np.asarray(u))))
    return du <= xtol or (value - value_new) <= ftol * abs(value)


def levenberg_marquardt(
    problem: Problem, u0, *, xtol, ftol, max_steps, progress, n_experiments
) -> Trace:
    """Minimise $\\tfrac12|r(u)|^2$ by Levenberg-Marquardt (optimistix).

    Every solver step simulates all experiments once (with sensitivities) at a
    trial point; a trial that does not lower the loss is rejected."""
    start = time.perf_counter()
    # optimistix's own (Cauchy) test is switched off: ours is `_small_step`.
    solver = optx.LevenbergMarquardt(rtol=0.0, atol=0.0, verbose=_record_trial)
    u = jnp.asarray(u0)
    trace = Trace(u=np.asarray(u))
    # optimistix damps with lambda I, lambda = 1 at the start. Solve instead for
    # v = (u - u0) * |J0 e_k| (unit Jacobian columns at the start, as MINPACK
    # scales), and multiply the residuals by c so that lambda = 1 is Marquardt's
    # lambda_0 = TAU max diag(J^T J). One extra evaluation at u0; the scalings are
    # traced values, so nothing recompiles.
    state = _lm_init(solver, u, problem)
    _, state, value, *_ = _lm_step(solver, u, state, problem)
    trace.n_simulations += n_experiments
    if not np.isfinite(float(value)):
        trace.wall_time = time.perf_counter() - start
        return trace  # the start failed: `identify` reports it
    _, J0 = _lm_final(state)
    norms = np.sqrt(np.sum(np.asarray(J0) ** 2, axis=0))
    live = norms > 1e-12 * max(float(np.max(norms)), 1e-300)
    u_scale = np.where(live, 1.0 / np.where(live, norms, 1.0), 1.0)
    scale = 1.0 / np.sqrt(TAU)
    problem = with_scaling(problem, scale, u, u_scale)
    u0_arr = u
    v = jnp.zeros_like(u)
    state = _lm_init(solver, v, problem)
    show = _Progress(progress, "Levenberg-Marquardt, forward-mode Jacobian")
    rejected_in_row = 0
    for _ in range(max_steps):
        u_prev = u
        v, state, value, gnorm, accepted, _, result = _lm_step(
            solver, v, state, problem
        )
        # Trial points with a higher loss are rejected: skip their Jacobians.
        problem = with_jacobian_loss_limit(problem, value)
        u = u0_arr + u_scale * v
        trace.n_simulations += n_experiments
        value = float(value) / scale**2
        gnorm = float(np.linalg.norm(np.asarray(gnorm) / u_scale)) / scale**2
        if bool(accepted):
            rejected_in_row = 0
            trace.n_iterations += 1
            trace.loss_history.append(value)
            trace.grad_norms.append(gnorm)
            show(trace.n_iterations, value, gnorm)
            last = trace.loss_history[-2] if len(trace.loss_history) > 1 else None
            if last is not None and _small_step(u_prev, u, last, value, xtol, ftol):
                trace.status = "converged"
                trace.reason = f"last step below xtol = {xtol} or ftol = {ftol}"
                break
        else:
            rejected_in_row += 1
            trace.n_rejected += 1
            if not np.isfinite(_TRIAL.loss):
                trace.n_failed_trials += 1
                show(trace.n_iterations, value, gnorm, "trial failed")
        if result != optx.RESULTS.successful:
            trace.status = "failed"
            trace.reason = str(optx.RESULTS[result])
            break
        if rejected_in_row >= MAX_REJECTIONS:
            trace.status = "converged"
            trace.reason = (
                f"no lower loss within a trust region shrunk {MAX_REJECTIONS} times "
                f"(minimum resolved to the accuracy of the simulations)"
            )
            break
    else:
        trace.reason = f"reached max_steps = {max_steps} solver steps"
    r, Jv = _lm_final(state)
    trace.residual = np.asarray(r) / scale
    trace.jacobian = np.asarray(Jv) / scale / u_scale[None, :]
    trace.u = np.asarray(u)
    trace.wall_time = time.perf_counter() - start
    return trace


@eqx.filter_jit
def _value_and_grad(u, problem):
    return jax.value_and_grad(loss)(u, problem)


@eqx.filter_jit
def _linesearch_step(optimizer, u, state, problem):
    """One update of a line-search optimiser (e.g. `optax.lbfgs`), reusing the value
    and gradient its line search stored at `u`."""

    def fun(v):
        return loss(v, problem)

    value, grad = optax.value_and_grad_from_state(fun)(u, state=state)
    updates, state = optimizer.update(
        grad, state, u, value=value, grad=grad, value_fn=fun
    )
    steps = optax.tree.get(state, "num_linesearch_steps")
    return optax.apply_updates(u, updates), state, value, grad, steps


@eqx.filter_jit
def _plain_update(optimizer, u, state, grad):
    updates, state = optimizer.update(grad, state, u)
    return updates, state


def optax_minimise(
    problem: Problem, u0, optimizer, *, xtol, ftol, max_steps, progress, n_experiments
) -> Trace:
    """Minimise $\\tfrac12|r(u)|^2$ with an optax optimiser and reverse-mode
    gradients, until a step is small (`_small_step`)."""
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
    if not linesearch:
        value, grad = _value_and_grad(u, problem)
        trace.n_simulations += n_experiments
    for _ in range(max_steps):
        if linesearch:
            u_new, state, value, grad, steps = _linesearch_step(
                optimizer, u, state, problem
            )
            # the first call also evaluates the loss at u0
            trace.n_simulations += n_experiments * (
                int(steps) + (trace.n_iterations == 0)
            )
            if trace.n_iterations == 0 and not np.isfinite(float(value)):
                break  # the start failed: `identify` reports it
            value_new = float(optax.tree.get(state, "value"))
            if not np.isfinite(value_new):
                trace.status = "stalled"
                trace.reason = "the line search found no finite lower loss"
                break
        else:
            if not np.isfinite(float(value)):
                break  # the start failed: `identify` reports it
            updates, state = _plain_update(optimizer, u, state, grad)
            for _halving in range(MAX_HALVINGS):
                u_new = u + updates
                value_new, grad_new = _value_and_grad(u_new, problem)
                trace.n_simulations += n_experiments
                if np.isfinite(float(value_new)):
                    break
                trace.n_failed_trials += 1
                trace.n_rejected += 1
                updates = 0.5 * updates
                show(trace.n_iterations, float(value), 0.0, "trial failed, halved")
            else:
                trace.status = "stalled"
                trace.reason = "no finite loss along the update direction"
                break
        if trace.n_iterations == 0:
            trace.loss_history.append(float(value))
        trace.n_iterations += 1
        gnorm = float(jnp.linalg.norm(grad))
        trace.loss_history.append(float(value_new))
        trace.grad_norms.append(gnorm)
        show(trace.n_iterations, float(value_new), gnorm)
        done = _small_step(u, u_new, float(value), float(value_new), xtol, ftol)
        u = u_new
        if not linesearch:
            value, grad = value_new, grad_new
        if done:
            trace.status = "converged"
            trace.reason = f"last step below xtol = {xtol} or ftol = {ftol}"
            break
    else:
        trace.reason = f"reached max_steps = {max_steps} iterations"
    trace.u = np.asarray(u)
    trace.wall_time = time.perf_counter() - start
    return trace
