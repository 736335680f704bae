"""`simulate`: a thin layer over `diffrax.diffeqsolve`."""

import numbers
from collections.abc import Callable
from functools import partial

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from ._compile_options import fast_compile_jit
from ._custom_types import (
    ArrayInput,
    BodyScalars,
    Scalar,
    State,
    TimeLike,
    Times,
    Validated,
)
from ._forces import (
    AbstractForce,
    check_force,
    jump_times,
    pad_to_bodies,
    sampled_interval,
)
from ._integrate import (
    MIN_STEP_ULPS,
    StepwiseAdjoint,
    StopFailedSteps,
    default_adjoint,
    default_lanes,
    integrate,
    locate_event,
    rms_norm,
    stability_radius,
)
from ._lagrange import (
    accelerations,
    constrained_accelerations,
    linear_rate_bound,
)
from ._models import AbstractElasticModel, MobileModel
from ._motion import PrescribedMotion
from ._options import SimulationOptions, check_initial_step, resolve_options
from ._status import Status, status_message
from ._trajectory import SimulationError as SimulationError, Trajectory
from ._validation import as_float_array, check_times, is_concrete, xp

# The state diffrax integrates: Y, its rate, the work done by the applied forces and
# the energy dissipated, packed into one vector `(12 bodies + 2,)` (`_pack`): the
# solver's stage sums, error norm and outputs then act on one array instead of four,
# which makes a step of one trajectory cheaper.
_ODEState = Float[Array, " state"]
# `args` of the vector field: model, force, the sign of each body's regularity at the
# start, the prescribed motion, and the end of the run.
_Args = tuple[
    AbstractElasticModel,
    AbstractForce | None,
    BodyScalars,
    PrescribedMotion | None,
    Scalar,
]


def simulate(
    model: Validated[AbstractElasticModel],
    y_init: ArrayInput,
    ydot_init: ArrayInput,
    ts: ArrayInput,
    forces: AbstractForce | Callable[..., ArrayInput] | ArrayInput | None = None,
    solver: diffrax.AbstractSolver | str | None = None,
    rtol: float | None = None,
    atol: float | None = None,
    max_steps: int | None = None,
    *,
    options: Validated[SimulationOptions | None] = None,
    dt0: float | None = None,
    adjoint: diffrax.AbstractAdjoint | StepwiseAdjoint | None = None,
    throw: Validated[bool | None] = None,
    gimbal_tol: float | None = None,
    link_tol: float | None = None,
    prescribed: Validated[PrescribedMotion | None] = None,
    progress_meter: diffrax.AbstractProgressMeter | None = None,
    batch_loop: bool | int | None = None,
) -> Trajectory:
    """Integrate $W(Y)\\ddot Y + w(Y, \\dot Y) = G + F$ from `ts[0]` to `ts[-1]`.

    **Arguments:**

    - `model`: an `ImmobileModel` or `MobileModel`.
    - `y_init`, `ydot_init`: $Y(t_0)$, $\\dot Y(t_0)$, shape `(bodies, 6)`.
    - `ts`: increasing output times [s]; the run starts at `ts[0]`.
    - `forces`: `None`, an array `(m, 6)` (constant), a `ConstantForce`,
      `SampledForce`, or a callable `f(t, y, ydot) -> (m, 6)`. A leading row for the
      object, shape `(m + 1, 6)`, adds a disturbance on it.
    - `options`: a `SimulationOptions`, the solver and its settings (default
      `SimulationOptions()`: `Dopri8` at rtol 1e-9, atol 1e-11, at most 100 000
      steps, and the thresholds `gimbal_tol`, `link_tol` of the two
      singularities).
    - `solver`, `rtol`, `atol`, `max_steps`, `gimbal_tol`, `link_tol`: deprecated
      spellings of the fields of `options` (a `DeprecationWarning`); given, each
      replaces that field of `options`.
    - `dt0`: initial step, a positive number (default: chosen by diffrax).
    - `adjoint`: how reverse-mode gradients are taken. The default (`None`):
      `StepwiseAdjoint()`, the discrete adjoint over the accepted steps, for the
      explicit Runge-Kutta solvers it supports (a gradient with respect to what it
      does not differentiate, such as the output times, is taken by diffrax's
      `RecursiveCheckpointAdjoint` instead), and
      `diffrax.RecursiveCheckpointAdjoint()` for other solvers. Or any diffrax
      adjoint: forward mode (`jax.jvp`, `jax.jacfwd`) needs
      `diffrax.ForwardMode()`.
    - `throw`: `None` (default) raises `SimulationError` for an early stop when the
      outcome is concrete (outside transformations, and under `jax.grad` without
      `jit`), and reports it in `Trajectory.status` under `jit` and `vmap` (each
      element of a batch on its own); `True` raises in both cases (also with the
      compilation cache on); `False` never raises.
    - `prescribed`: a `PrescribedMotion`: the coordinates in its mask follow its
      motion (their entries of `y_init`, `ydot_init` are taken from it) and only the
      others are integrated; `Trajectory.reaction` then holds the generalized forces
      that realise the prescribed motion, and `Trajectory.work` includes their work.
    - `progress_meter`: a diffrax progress meter, e.g.
      `diffrax.TqdmProgressMeter()` for a progress bar on a long run (default none).
    - `batch_loop`: how a `jax.vmap`-ed batch is integrated. The default (`None`)
      is the batch loop in lanes where the solve's derivatives are the default
      adjoint's (or `StepwiseAdjoint`'s), else `False`. The batch loop integrates
      the whole batch in one loop, each element with its own steps, instead of
      `vmap`-ing diffrax's loop: faster (`benchmarks/loop.py`), the same steps,
      each equal to diffrax's to rounding (results within the solver's tolerance
      of it). An integer $n \\geq 1$: at most $n$ elements at once (lanes); when
      one stops, the next one still waiting starts in its place, so that a batch
      much wider than $n$ never waits for its slowest elements with most of its
      places idle. The default takes `default_lanes()` lanes (128 on a CPU, the
      whole batch on an accelerator). `True`: the whole batch at once; `False`:
      `vmap` of diffrax's loop. Each element's results do not depend on $n$ and
      equal those of `batch_loop=True` to rounding. Explicit Runge-Kutta solvers
      without a progress meter; otherwise ignored. With a diffrax adjoint the
      batch loop is not differentiable (forward or reverse); with the stepwise
      adjoint it is in reverse mode.

    **Returns:** a `Trajectory`. Differentiable with respect to every array in the
    model, the initial state and the forces (`event_time`, where a run stopped
    early, is not differentiated), and `jax.vmap`-able over any of them.

    No step is longer than the solver's stability radius over a bound of the rates
    of the motion linearized at the start (`_integrate.stability`): where nothing
    moves, as at rest in an equilibrium, the error control would otherwise let the
    steps grow until the unseen fast modes are unstable, and the derivatives, which
    follow them, would be wrong by orders of magnitude. An explicit solver's step
    is bounded so; an implicit one's is not.

    A run stops at once, with its own `Status`, at NaN or inf in the state, the
    forces or the step size (`NONFINITE`), when the step size collapses on finite
    values (`SOLVER_FAILED`), and when it reaches a time outside the samples of a
    `SampledForce` (`OUTSIDE_FORCE_SAMPLES`). Traced inputs that are not finite are
    reported the same way rather than raised, so that in a batch one bad element
    never affects the others, and so is a traced model whose values its
    constructor would refuse (`INVALID_MODEL`: not simulated; for an
    `ImmobileModel` the definiteness of K and D is not checked there).
    """
    if not isinstance(model, AbstractElasticModel):
        raise ValueError(
            f"model must be an ImmobileModel or MobileModel, got {type(model).__name__}"
        )
    options = resolve_options(
        options,
        "simulate",
        solver=solver,
        rtol=rtol,
        atol=atol,
        max_steps=max_steps,
        gimbal_tol=gimbal_tol,
        link_tol=link_tol,
    )
    return _simulate(
        model,
        y_init,
        ydot_init,
        ts,
        forces,
        options,
        dt0=dt0,
        adjoint=adjoint,
        throw=throw,
        prescribed=prescribed,
        progress_meter=progress_meter,
        batch_loop=batch_loop,
    )


def _simulate(
    model: AbstractElasticModel,
    y_init: ArrayInput,
    ydot_init: ArrayInput,
    ts: ArrayInput,
    forces: AbstractForce | Callable[..., ArrayInput] | ArrayInput | None,
    options: SimulationOptions,
    *,
    dt0: float | None = None,
    adjoint: diffrax.AbstractAdjoint | StepwiseAdjoint | None = None,
    throw: Validated[bool | None] = None,
    prescribed: Validated[PrescribedMotion | None] = None,
    progress_meter: diffrax.AbstractProgressMeter | None = None,
    batch_loop: bool | int | None = None,
    step_limit: Int[Array, ""] | None = None,
) -> Trajectory:
    """`simulate` with its options resolved, and a `step_limit`: a traced limit on
    the solver steps below the options' `max_steps` (a run reaching it stops with
    `Status.MAX_STEPS_REACHED`, as at `max_steps`), so that runs under different
    limits share one compiled program."""
    if batch_loop is not None and (
        not isinstance(batch_loop, bool)
        and (not isinstance(batch_loop, numbers.Integral) or batch_loop < 1)
    ):
        raise ValueError(
            f"batch_loop must be True, False or a positive integer, got {batch_loop!r}"
        )
    if throw is not None and not isinstance(throw, bool | np.bool_):
        raise ValueError(f"simulate.throw must be True, False or None, got {throw!r}")
    diffrax_solver = options.diffrax_solver()
    fallback = False
    if adjoint is None:
        adjoint, fallback = default_adjoint(diffrax_solver)
    if batch_loop is None:
        batch_loop = default_lanes() if isinstance(adjoint, StepwiseAdjoint) else False
    if is_concrete(dt0):
        check_initial_step(dt0, "simulate")
    if is_concrete(model) and not bool(model.admissible()):
        reason = model.refusal() or "a value out of the range of its parameter"
        raise ValueError(
            f"model has values its constructor refuses: {reason} (a model changed "
            f"with eqx.tree_at is not checked again until it is simulated)"
        )
    n = model.n_bodies
    # Traced non-finite states are reported in `Trajectory.status`, lane by lane.
    y_init = jnp.asarray(as_float_array(y_init, "y_init", (n, 6), check_traced=False))
    ydot_init = jnp.asarray(
        as_float_array(ydot_init, "ydot_init", (n, 6), check_traced=False)
    )
    ts = jnp.asarray(check_times(ts, "ts"))
    if prescribed is not None:
        if not isinstance(prescribed, PrescribedMotion):
            raise ValueError(
                "prescribed must be a PrescribedMotion, got "
                f"{type(prescribed).__name__}"
            )
        prescribed.check(n, ts[0], ts[-1])
        y_init, ydot_init, _ = prescribed.impose(ts[0], y_init, ydot_init)
    force = check_force(forces, y_init, ydot_init, ts)
    if is_concrete(y_init):
        angles = np.asarray(y_init)[:, 3:]
        model.rotation.check_regular(angles, options.gimbal_tol, "y_init")
        if (
            isinstance(model, MobileModel)
            and model.n_connections > 0
            and is_concrete(model)
        ):
            _check_links_open(model, y_init, options.link_tol)

    # The step bound of a concrete model and start (both checked above), in a
    # program of its own (compiled once for each model structure, not into every
    # run's program); a traced one is bounded inside the run's program.
    step_bound = None
    if is_concrete(model) and is_concrete(y_init):
        step_bound = _compiled_step_bound(model, y_init, diffrax_solver)
    traj = _solve(
        model,
        y_init,
        ydot_init,
        ts,
        force,
        diffrax_solver,
        float(options.rtol),
        float(options.atol),
        int(options.max_steps),
        dt0,
        adjoint,
        float(options.gimbal_tol),
        float(options.link_tol),
        prescribed,
        diffrax.NoProgressMeter() if progress_meter is None else progress_meter,
        batch_loop,
        fallback,
        step_limit,
        step_bound,
    )
    if throw is False:
        return traj
    if is_concrete(traj.status):
        if int(traj.status) != Status.SUCCESS:
            raise SimulationError(status_message(traj), traj)
    elif throw:
        # Raises whatever equinox's error mode (the compilation cache switches it to
        # "nan"): `throw=True` asks for an error.
        y = eqx.error_if(
            traj.y,
            traj.status != Status.SUCCESS,
            "simulation stopped early (gimbal lock, collapsed link, non-finite "
            "values, the end of the force samples or solver failure); run with "
            "throw=False and inspect Trajectory.status",
            on_error="raise",
        )
        traj = eqx.tree_at(lambda t: t.y, traj, y)
    return traj


def _applied(
    model: AbstractElasticModel,
    force: AbstractForce | None,
    t: TimeLike,
    y: State,
    ydot: State,
) -> State:
    if force is None:
        return jnp.zeros_like(y)
    return pad_to_bodies(force(t, y, ydot), model.n_bodies)


def _pack(y: State, ydot: State, work: Scalar, dissipated: Scalar) -> _ODEState:
    """`(Y, Y', work, dissipated)` -> one vector: Y and Y' body-major, then the two
    scalars."""
    scalars = jnp.stack([work, dissipated])
    return jnp.concatenate([y.ravel(), ydot.ravel(), scalars])


def _unpack(x: Float[Array, "*times state"]) -> tuple[Array, Array, Array, Array]:
    """The inverse of `_pack`, also for a leading axis of output times (one split:
    its transpose in a gradient is one concatenation)."""
    lead, size = x.shape[:-1], x.shape[-1]
    n = (size - 2) // 2
    y, ydot, work, dissipated = jnp.split(x, [n, 2 * n, 2 * n + 1], axis=-1)
    shape = (*lead, n // 6, 6)
    return y.reshape(shape), ydot.reshape(shape), work[..., 0], dissipated[..., 0]


# Jitted on its own: the solver's step is traced several times over (the forward
# loop, the checkpointed backward pass, linearization and transposition), and JAX
# traces a jitted function once per signature and caches its transformations. This
# shortens tracing a reverse-mode gradient; the compiled program is
# the same (XLA inlines the call).
@eqx.filter_jit
def _vector_field(t: TimeLike, state: _ODEState, args: _Args) -> _ODEState:
    model, force, _, prescribed, _ = args
    y, ydot, _, _ = _unpack(state)
    if prescribed is None:
        applied = _applied(model, force, t, y, ydot)
        yddot, damping = accelerations(model, y, ydot, applied)
        return _pack(ydot, yddot, jnp.sum(applied * ydot), jnp.sum(damping * ydot))
    y, ydot, yddot, damping, reaction, applied = _driven(
        model, force, prescribed, t, y, ydot
    )
    power = jnp.sum((applied + reaction) * ydot)
    return _pack(ydot, yddot, power, jnp.sum(damping * ydot))


def _driven(
    model: AbstractElasticModel,
    force: AbstractForce | None,
    prescribed: PrescribedMotion,
    t: TimeLike,
    y: State,
    ydot: State,
) -> tuple[State, State, State, State, State, State]:
    """The state with the prescribed entries substituted, and its dynamics."""
    y, ydot, yddot_p = prescribed.impose(t, y, ydot)
    applied = _applied(model, force, t, y, ydot)
    yddot, damping, reaction = constrained_accelerations(
        model, y, ydot, applied, prescribed.mask, yddot_p
    )
    return y, ydot, yddot, damping, reaction, applied


def _of_state(
    condition: Callable, t: TimeLike, state: _ODEState, args: _Args
) -> Scalar:
    """A stop condition of $Y$ as a condition of the ODE state."""
    return condition(t, _unpack(state)[0], args)


def _stable_step(
    model: AbstractElasticModel, y: State, solver: diffrax.AbstractSolver
) -> Scalar:
    """The longest step `simulate` takes: the solver's stability radius over a
    bound of the rates of the motion linearized at the start (`linear_rate_bound`;
    `_integrate.stability` says why), `inf` where there is none (no elastic or
    damping force, an implicit solver, or a start that is not finite). Held
    constant under differentiation: a step size has no derivative."""
    radius = stability_radius(solver)
    if not np.isfinite(radius):
        return jnp.asarray(jnp.inf, y.dtype)
    rate = linear_rate_bound(jax.lax.stop_gradient(model), jax.lax.stop_gradient(y))
    ok = jnp.isfinite(rate) & (rate > 0)
    return jnp.where(ok, radius / jnp.where(ok, rate, 1.0), jnp.inf)


@fast_compile_jit
def _compiled_step_bound(
    model: AbstractElasticModel, y: State, solver: diffrax.AbstractSolver
) -> Array:
    """`_stable_step` of a concrete model and start, in its own compiled program
    (one for each model structure and solver)."""
    return _stable_step(model, y, solver)


def _regularity(model: AbstractElasticModel, y: State) -> BodyScalars:
    return jax.vmap(model.rotation.regularity)(y[:, 3:])


def _link_margin(
    model: MobileModel, y: Float[Array | np.ndarray, "bodies 6"], link_tol: float
) -> Float[Array | np.ndarray, " connections"]:
    """$|r_i - r_j| - tol\\,\\rho_0$ per link; links with $\\rho_0 = 0$ never stop."""
    np_ = xp(y, model.rest_length)  # NumPy for `_check_links_open`
    d = y[model.pairs[:, 0], :3] - y[model.pairs[:, 1], :3]
    margin = np_.sqrt(np_.sum(d * d, axis=-1)) - link_tol * model.rest_length
    return np_.where(model.rest_length > 0, margin, np_.inf)


def _check_links_open(model: MobileModel, y_init: State, link_tol: float) -> None:
    """Raise `ValueError` if a link of the concrete `y_init` starts at or below
    the collapse threshold: the stop condition fires only when a link falls
    through it, so a run started below it would go on unchecked."""
    # in NumPy: JAX operations one by one would each compile on first use
    model = jax.tree.map(np.asarray, model)
    y = np.asarray(y_init)
    margin = _link_margin(model, y, link_tol)
    if np.any(margin <= 0):
        k = int(np.argmin(margin))
        i, j = (int(v) for v in model.pairs[k])
        rest = float(model.rest_length[k])
        length = float(margin[k]) + link_tol * rest
        raise ValueError(
            f"y_init: connection {k} between bodies {i} and {j} starts collapsed: "
            f"|r_i - r_j| = {length:.6g} m is not above link_tol x rest length = "
            f"{link_tol:g} x {rest:.6g} m (its deflection has no direction at zero "
            f"length); separate the bodies, or lower link_tol"
        )


@fast_compile_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (get_num_traces)
def _solve(
    model: AbstractElasticModel,
    y_init: State,
    ydot_init: State,
    ts: Times,
    force: AbstractForce | None,
    solver: diffrax.AbstractSolver,
    rtol: float,
    atol: float,
    max_steps: int,
    dt0: float | None,
    adjoint: diffrax.AbstractAdjoint | StepwiseAdjoint,
    gimbal_tol: float,
    link_tol: float,
    prescribed: PrescribedMotion | None,
    progress_meter: diffrax.AbstractProgressMeter,
    batch_loop: bool | int = False,
    fallback: bool = False,
    step_limit: Int[Array, ""] | None = None,
    step_bound: Scalar | None = None,
) -> Trajectory:
    # Starts that are not simulated (only possible when traced; concrete ones are
    # refused by `simulate`): NaN or inf in the initial state, a start at the
    # singularity, with a link collapsed, or before the force samples. Each is
    # flagged, and a regular, finite state stands in for the one solver step taken,
    # so a batch stays finite.
    start_finite = jnp.isfinite(y_init).all(axis=1) & jnp.isfinite(ydot_init).all(
        axis=1
    )
    # (the checks of construction that need no eigenvalue decomposition: a
    # concrete model was checked whole before)
    invalid0 = ~jnp.asarray(model.admissible(definiteness=False))
    nonfinite0 = ~invalid0 & ~jnp.all(start_finite)
    reg0 = _regularity(model, y_init)
    singular0 = ~nonfinite0 & jnp.any(jnp.abs(reg0) < gimbal_tol)
    interval = sampled_interval(force)
    if interval is None:
        before_samples0 = jnp.array(False)
    else:
        before_samples0 = ts[0] < interval[0]
    if isinstance(model, MobileModel) and model.n_connections > 0:
        margin0 = _link_margin(model, y_init, link_tol)
        collapsed0 = ~nonfinite0 & ~singular0 & jnp.any(margin0 <= 0)
        shortest0 = jnp.argmin(margin0)
    else:
        collapsed0, shortest0 = jnp.array(False), jnp.asarray(-1)
    halt = invalid0 | nonfinite0 | singular0 | collapsed0 | before_samples0
    # The signed measure keeps its initial sign until the singularity is crossed,
    # so `side * measure - tol` changes sign even when one step jumps the band.
    side = jnp.where(reg0 < 0, -1.0, 1.0)
    regular = jnp.asarray(model.rotation.regular_angles)
    y_safe = jnp.where(jnp.isfinite(y_init), y_init, 0.0).at[:, 3:].set(regular)
    y_start = jnp.where(halt, y_safe, y_init)
    ydot_start = jnp.where(halt, 0.0, ydot_init)

    # Stop conditions, functions of t, Y and args.
    def gimbal(t, y, args):
        return jnp.min(args[2] * _regularity(args[0], y)) - gimbal_tol

    cond_fns = {"gimbal": gimbal}
    if isinstance(model, MobileModel) and model.n_connections > 0:

        def collapse(t, y, args):
            return jnp.min(_link_margin(args[0], y, link_tol))

        cond_fns["collapse"] = collapse
    if interval is not None:
        # The run stops where the samples end, if that is before ts[-1] (like the
        # others, this event fires where its value falls to zero from above).
        def samples_end(t, y, args):
            samples = sampled_interval(args[1])
            assert samples is not None  # (the force of `interval`)
            end = samples[1]
            return jnp.where(args[4] <= end, 1.0, end - t)

        cond_fns["samples_end"] = samples_end
    # No root finder: the solve ends at the end of the step in which a condition
    # changed sign, and `locate_event` finds the crossing in that step.
    controller: diffrax.AbstractAdaptiveStepSizeController
    if step_bound is None:
        step_bound = _stable_step(model, y_start, solver)
    controller = diffrax.PIDController(
        rtol=rtol, atol=atol, norm=rms_norm, dtmax=step_bound
    )
    jump_ts = jump_times(force)
    if jump_ts is not None:
        controller = diffrax.ClipStepSizeController(controller, jump_ts=jump_ts)
    resolution = jnp.finfo(ts.dtype).eps * jnp.maximum(jnp.abs(ts[0]), jnp.abs(ts[-1]))
    controller = StopFailedSteps(
        controller, MIN_STEP_ULPS * resolution, halt, step_limit=step_limit
    )
    zero = jnp.zeros((), dtype=y_init.dtype)
    args = (model, force, side, prescribed, ts[-1])
    sol = integrate(
        _vector_field,
        solver,
        _pack(y_start, ydot_start, zero, zero),
        args,
        ts,
        controller,
        [partial(_of_state, fn) for fn in cond_fns.values()],
        max_steps,
        dt0=dt0,
        adjoint=adjoint,
        progress_meter=progress_meter,
        batch_loop=batch_loop,
        fallback=fallback,
    )
    y_all, ydot_all, work, dissipated = _unpack(sol.ys)
    reaction = None
    if prescribed is not None:
        # Report the prescribed entries exactly, and the reactions at the outputs.
        def exact(t, y, ydot):
            y, ydot, _, _, reaction, _ = _driven(model, force, prescribed, t, y, ydot)
            return y, ydot, reaction

        # Unused output slots hold t = inf; evaluate them at ts[0] (masked below).
        t_out = jnp.where(jnp.isfinite(sol.ts), sol.ts, ts[0])
        y_all, ydot_all, reaction = jax.vmap(exact)(t_out, y_all, ydot_all)
    # With SaveAt(ts, t1) the final state follows the last saved time <= t_end
    # (diffrax compacts the outputs), and the unused entries are inf.
    last = jnp.argmax(jnp.where(jnp.isfinite(sol.ts), sol.ts, -jnp.inf))
    t_end = sol.ts[last]
    y_end = y_all[last]
    ydot_end = ydot_all[last]
    record = sol.controller_state

    event_hit = sol.result == diffrax.RESULTS.event_occurred
    hits = {
        name: event_hit & mask
        for name, mask in zip(cond_fns, sol.event_mask, strict=True)
    }
    no_hit = jnp.array(False)
    step_failed = sol.result == diffrax.RESULTS.dt_min_reached

    # Where an event ended the run, diffrax stopped at the end of the step in which
    # its condition changed sign: the run ends at the crossing inside that step
    # (not differentiated, see `locate_event`).
    def crossing(t_start, y_start, t_stop, y_stop, ydot_stop):
        t_event, y_event, ydot_event = locate_event(
            t_start,
            t_stop,
            _unpack(y_start)[:2],
            (y_stop, ydot_stop),
            args,
            list(cond_fns.values()),
            sol.event_mask,
        )
        if prescribed is not None:
            y_event, ydot_event, _ = prescribed.impose(t_event, y_event, ydot_event)
        return t_event, y_event, ydot_event

    def step_end(t_start, y_start, t_stop, y_stop, ydot_stop):
        return t_stop, y_stop, ydot_stop

    t_end, y_end, ydot_end = jax.lax.cond(
        event_hit,
        crossing,
        step_end,
        *jax.lax.stop_gradient(
            (record.t_start, record.y_start, t_end, y_end, ydot_end)
        ),
    )
    status = jnp.select(
        [
            invalid0,
            nonfinite0,
            singular0,
            collapsed0,
            before_samples0,
            hits["gimbal"],
            hits.get("collapse", no_hit),
            hits.get("samples_end", no_hit),
            sol.result == diffrax.RESULTS.max_steps_reached,
            step_failed & record.nonfinite,
            ~(event_hit | (sol.result == diffrax.RESULTS.successful)),
        ],
        [
            Status.INVALID_MODEL,
            Status.NONFINITE,
            Status.GIMBAL_LOCK,
            Status.LINK_COLLAPSED,
            Status.OUTSIDE_FORCE_SAMPLES,
            Status.GIMBAL_LOCK,
            Status.LINK_COLLAPSED,
            Status.OUTSIDE_FORCE_SAMPLES,
            Status.MAX_STEPS_REACHED,
            Status.NONFINITE,
            Status.SOLVER_FAILED,
        ],
        Status.SUCCESS,
    )
    if isinstance(model, MobileModel) and "collapse" in hits:
        worst_link = jnp.argmin(_link_margin(model, y_end, link_tol))
    else:
        worst_link = jnp.asarray(-1)
    # The body whose initial state, or whose force where the run stopped, is not
    # finite (-1 when both are finite everywhere). A collapsed step ends within a
    # few units in the last place of `t_end`: the force is evaluated at the time it
    # tried to reach, and at the last state.
    t_force = jnp.where(jnp.isfinite(record.t_tried), record.t_tried, t_end)
    applied_end = _applied(model, force, t_force, y_end, ydot_end)
    force_finite = jnp.isfinite(applied_end).all(axis=1)
    bad_rows = ~(start_finite & force_finite)
    bad_body = jnp.where(jnp.any(bad_rows), jnp.argmax(bad_rows), -1)
    index = jnp.select(
        [
            nonfinite0,
            singular0,
            collapsed0,
            hits["gimbal"],
            hits.get("collapse", no_hit),
            status == Status.NONFINITE,
        ],
        [
            jnp.argmax(~start_finite),
            jnp.argmin(jnp.abs(reg0)),
            shortest0,
            jnp.argmin(side * _regularity(model, y_end)),
            worst_link,
            bad_body,
        ],
        -1,
    )
    event_time = jnp.where(halt, ts[0], t_end)
    failed = status != Status.SUCCESS
    after = failed & (ts > event_time) | halt

    def mask(x):
        x = x[:-1]
        shape = (-1,) + (1,) * (x.ndim - 1)
        return jnp.where(after.reshape(shape), jnp.nan, x)

    return Trajectory(
        ts=ts,
        y=mask(y_all),
        ydot=mask(ydot_all),
        work=mask(work),
        dissipated=mask(dissipated),
        model=model,
        status=status.astype(jnp.int32),
        event_time=event_time,
        event_index=index.astype(jnp.int32),
        reaction=None if reaction is None else mask(reaction),
        n_steps=jnp.asarray(sol.num_steps, jnp.int32),
    )
