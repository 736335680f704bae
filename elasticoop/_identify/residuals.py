"""Output error: weighted residuals of simulated against measured trajectories.

For experiment $e$, sample $k$, body $i$ and coordinate $c$,
$$r_{eki c}(u) = \\frac{Y^{\\rm sim}_{ic}(t_k; p(u)) - Y^{\\rm data}_{ekic}}
{\\sigma_{eic}}$$
(and likewise for $\\dot Y$ when it was measured), zero for missing (NaN) samples.
The loss is $\\tfrac12 \\sum r^2$. Experiments of equal shapes are simulated by one
`vmap`-ed call of `simulate`.

The unknowns $u$ are the reparameterised free parameters, then (with
`fit_initial`) the corrections $\\Delta_e$ of the experiments' initial states
(see `initial_state`), experiment by experiment in batch order. Parameters held
fixed (`held`) take the values `u_held` whatever $u$ says: their sensitivities are
zero and the optimiser leaves them alone.

A simulation that stops early (gimbal lock, a collapsed link, solver failure) or
produces non-finite values gives residuals $+\\infty$ for its experiment: the loss
of that trial point is infinite, so a line search or trust region rejects it and
shortens the step instead of failing.
"""

import dataclasses

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Int

from .._analysis import rest_state
from .._forces import PoseTracking, pad_to_bodies
from .._lagrange import elastic_forces
from .._options import SimulationOptions
from .._simulate import _simulate
from .experiment import Experiment, batch_experiments
from .parameters import FreeParameters


class _Data(eqx.Module):
    """One batch of experiments of equal shapes, with NaN-free data and weights."""

    experiments: Experiment  # stacked along a leading batch axis
    y: jax.Array  # NaN replaced by 0
    y_weight: jax.Array  # 1/sigma where measured, 0 where missing
    ydot: jax.Array | None
    ydot_weight: jax.Array | None


def _prepare(stacked: Experiment) -> _Data:
    def clean(values, sigma):
        values = np.asarray(values)
        measured = np.isfinite(values)
        inv = 1.0 if sigma is None else 1.0 / np.asarray(sigma)[:, None]
        weight = measured * inv
        return jnp.asarray(np.where(measured, values, 0.0)), jnp.asarray(weight)

    y, yw = clean(stacked.y, stacked.sigma)
    ydot = ydw = None
    if stacked.ydot is not None:
        ydot, ydw = clean(stacked.ydot, stacked.sigma_ydot)
    return _Data(stacked, y, yw, ydot, ydw)


class FitProblem(eqx.Module):
    """Everything the residuals depend on besides $u$ (a pytree; no closures)."""

    model: eqx.Module
    free: FreeParameters
    batches: tuple[_Data, ...]
    order: tuple[int, ...] = eqx.field(static=True)  # experiment index per row
    options: SimulationOptions
    scale: jax.Array  # a constant factor on all residuals (solver conditioning)
    u_offset: jax.Array  # u = u_offset + u_scale * v, v the solver's variables
    u_scale: jax.Array
    # The Jacobian is computed only where the loss is at most this (+inf: always);
    # see `residuals_jacobian_and_runs`.
    jacobian_loss_limit: jax.Array
    # Which parts of the initial states are estimated: (positions, rates).
    fit_initial: tuple[bool, bool] = eqx.field(static=True)
    # Free parameters held at `u_held` (reparameterised values), not fitted.
    held: jax.Array
    u_held: jax.Array
    # Whether experiments that started at rest (`Experiment.rest`) start from the
    # rest state of the parameters evaluated (recomputed at every evaluation).
    rest: bool = eqx.field(static=True, default=False)
    # Whether a pose tracking's feedforward of an experiment at rest is the force
    # that holds its contact bodies in that rest state (recomputed with it),
    # rather than the experiment's numbers.
    hold_at_rest: bool = eqx.field(static=True, default=False)
    # The most solver steps of a simulation without sensitivities (None: the
    # options' `max_steps`); see `step_budget.py`. An array, the traced step
    # limit of a simulation compiled for the options' `max_steps`: every budget
    # runs the same program. The simulations with sensitivities, taken only where
    # the one without succeeded, run under the options' `max_steps`.
    step_budget: Int[Array, ""] | None = None

    @property
    def max_steps(self) -> int:
        """The most solver steps of a simulation without sensitivities."""
        if self.step_budget is None:
            return int(self.options.max_steps)
        return int(self.step_budget)

    @property
    def n_residuals(self) -> int:
        """The length of the residual vector."""
        return sum(
            b.y.size * (1 if b.ydot is None or b.ydot_weight is None else 2)
            for b in self.batches
        )

    @property
    def n_parameters(self) -> int:
        """The number of free model parameters (the first entries of $u$)."""
        return self.free.size

    @property
    def n_initial(self) -> int:
        """The number of estimated initial-state entries (the rest of $u$)."""
        parts = sum(self.fit_initial)
        # b.y is (batch, times, bodies, 6): one (bodies, 6) state per experiment
        return sum(
            parts * b.y.shape[0] * b.y.shape[2] * b.y.shape[3] for b in self.batches
        )

    @property
    def size(self) -> int:
        """The length of $u$."""
        return self.n_parameters + self.n_initial


def make_problem(
    model,
    free,
    experiments,
    options,
    fit_initial=(False, False),
    rest=False,
    hold_at_rest=False,
) -> FitProblem:
    groups = batch_experiments(experiments)
    order = tuple(k for indices, _ in groups for k in indices)
    batches = tuple(_prepare(stacked) for _, stacked in groups)
    one = jnp.ones((), jnp.float64)
    problem = FitProblem(
        model,
        free,
        batches,
        order,
        options,
        one,
        jnp.zeros(0),
        jnp.zeros(0),
        one * jnp.inf,
        (bool(fit_initial[0]), bool(fit_initial[1])),
        jnp.zeros(free.size, bool),
        jnp.zeros(free.size, jnp.float64),
        bool(rest),
        bool(rest and hold_at_rest),
    )
    zeros = jnp.zeros(problem.size, jnp.float64)
    return eqx.tree_at(lambda p: (p.u_offset, p.u_scale), problem, (zeros, zeros + 1.0))


def with_held(problem: FitProblem, held, u_held) -> FitProblem:
    """The same problem with the free parameters where `held` is true fixed at the
    reparameterised values `u_held` (traced values: no recompilation)."""
    return eqx.tree_at(
        lambda p: (p.held, p.u_held),
        problem,
        (jnp.asarray(held, bool), jnp.asarray(u_held, jnp.float64)),
    )


def with_scaling(problem: FitProblem, scale, u_offset, u_scale) -> FitProblem:
    """The same problem with residuals multiplied by `scale` and the solver's
    variables $v$ mapped to $u = $ `u_offset + u_scale * v` (traced values: no
    recompilation)."""
    values = (scale, u_offset, u_scale)
    return eqx.tree_at(
        lambda p: (p.scale, p.u_offset, p.u_scale),
        problem,
        tuple(jnp.asarray(x, jnp.float64) for x in values),
    )


def with_step_budget(problem: FitProblem, max_steps: int | None) -> FitProblem:
    """The same problem with the simulations without sensitivities allowed
    `max_steps` solver steps (at most the options' `max_steps`; None: no budget,
    the options' `max_steps`). A traced value: `evaluate` compiles once for every
    budget (and once without one)."""
    budget = None
    if max_steps is not None:
        limit = min(int(max_steps), int(problem.options.max_steps))
        budget = jnp.asarray(limit, jnp.int32)
    return dataclasses.replace(problem, step_budget=budget)


def with_static_budget(problem: FitProblem) -> FitProblem:
    """The same problem with its step budget as its options' `max_steps`, a static
    setting (a compiled program for each budget), instead of a traced limit. For
    reverse-mode gradients: `StepwiseAdjoint` records the steps in buffers sized by
    the static `max_steps`, which a traced budget would leave at the cap."""
    if problem.step_budget is None:
        return problem
    options = dataclasses.replace(problem.options, max_steps=problem.max_steps)
    return dataclasses.replace(problem, options=options, step_budget=None)


def with_jacobian_loss_limit(problem: FitProblem, limit) -> FitProblem:
    """The same problem computing Jacobians only where the loss (of the scaled
    residuals) is at most `limit` (a traced value: no recompilation)."""
    return eqx.tree_at(
        lambda p: p.jacobian_loss_limit, problem, jnp.asarray(limit, jnp.float64)
    )


def _simulate_batch(
    model,
    data: _Data,
    y_init,
    ydot_init,
    options: SimulationOptions,
    adjoint,
    hold_at_rest: bool = False,
    step_limit: Int[Array, ""] | None = None,
):
    hold = (
        hold_at_rest
        and data.experiments.rest is not None
        and isinstance(data.experiments.forces, PoseTracking)
    )

    def one(e: Experiment, y0, ydot0):
        forces = e.forces
        if hold:
            # the feedforward that holds the contact bodies at rest in y0
            held = (elastic_forces(model, y0) - model.gravity_forces())[1:]
            forces = eqx.tree_at(lambda f: f.feedforward, forces, held)
        return _simulate(
            model,
            y0,
            ydot0,
            e.ts,
            forces,
            options,
            adjoint=adjoint,
            throw=False,
            step_limit=step_limit,
        )

    return eqx.filter_vmap(one)(data.experiments, y_init, ydot_init)


def _rest_states(model, data: _Data) -> tuple[jax.Array, jax.Array]:
    """The batch's initial states at rest: $Y(t_0)$ the `rest_state` of `model`
    with the held coordinates at their values in `y_init` (the free ones start
    there), under the applied forces at rest at $t_0$ as numbers; $\\dot Y = 0$."""
    held = np.asarray(data.experiments.rest, dtype=bool)
    n = held.shape[0]

    def one(e: Experiment):
        y_guess = e.y_init
        F = None
        if e.forces is not None:
            at_rest = e.forces(e.ts[0], y_guess, jnp.zeros_like(y_guess))
            F = pad_to_bodies(jnp.asarray(at_rest), n)
        return rest_state(model, y_guess, F, held, throw=False)

    y0 = eqx.filter_vmap(one)(data.experiments)
    return y0, jnp.zeros_like(y0)


def initial_states(u, problem: FitProblem) -> list[tuple[jax.Array, jax.Array]]:
    """The initial states $(Y(t_0), \\dot Y(t_0))$ each batch's simulations start
    from at $u$, each `(batch, bodies, 6)`: with `problem.rest`, for experiments
    that started at rest (`Experiment.rest`), the rest state of the parameters at
    $u$ (NaN where it is not found: the evaluation fails); otherwise the
    experiments' `y_init`, `ydot_init` plus the estimated corrections
    $\\Delta_e$ held in $u$ after the parameters."""
    positions, rates = problem.fit_initial
    offset = problem.n_parameters
    out = []
    model = fitted_model(u, problem) if problem.rest else None
    for data in problem.batches:
        if model is not None and data.experiments.rest is not None:
            out.append(_rest_states(model, data))
            continue
        y0, ydot0 = data.experiments.y_init, data.experiments.ydot_init
        for fitted, name in ((positions, "y"), (rates, "ydot")):
            if not fitted:
                continue
            size = int(np.prod(y0.shape))
            delta = u[offset : offset + size].reshape(y0.shape)
            offset += size
            if name == "y":
                y0 = y0 + delta
            else:
                ydot0 = ydot0 + delta
        out.append((y0, ydot0))
    return out


def fitted_model(u, problem: FitProblem):
    """The model at $u$: the free parameters $p = g(u)$, the held ones at their
    held values."""
    u_model = jnp.where(problem.held, problem.u_held, u[: problem.n_parameters])
    return problem.free.apply(problem.model, u_model)


class Runs(eqx.Module):
    """How the simulations of one evaluation went, one entry per experiment (in
    batch order): whether it succeeded with finite residuals, its `Status` code and
    the solver steps it took."""

    ok: Bool[Array, " experiments"]
    status: Int[Array, " experiments"]
    steps: Int[Array, " experiments"]


def residuals_by_experiment(
    u, problem: FitProblem, adjoint=None
) -> tuple[list[jax.Array], Runs]:
    """Residuals per batch, each `(batch, times, bodies, 6)` (or twice that length
    along the last axis with measured $\\dot Y$), and how each simulation went
    (`Runs`)."""
    model = fitted_model(u, problem)
    out, ok_all, status, steps = [], [], [], []
    for data, (y0, ydot0) in zip(problem.batches, initial_states(u, problem)):
        traj = _simulate_batch(
            model,
            data,
            y0,
            ydot0,
            problem.options,
            adjoint,
            problem.hold_at_rest,
            problem.step_budget,
        )
        r = jnp.where(data.y_weight > 0, (traj.y - data.y) * data.y_weight, 0.0)
        if data.ydot is not None and data.ydot_weight is not None:  # set together
            rd = jnp.where(
                data.ydot_weight > 0, (traj.ydot - data.ydot) * data.ydot_weight, 0.0
            )
            r = jnp.concatenate([r, rd], axis=-1)
        ok = (traj.status == 0) & jnp.all(jnp.isfinite(r), axis=(1, 2, 3))
        r = jnp.where(ok[:, None, None, None], problem.scale * r, jnp.inf)
        out.append(r)
        ok_all.append(ok)
        status.append(traj.status)
        steps.append(traj.n_steps)
    runs = Runs(
        jnp.concatenate(ok_all), jnp.concatenate(status), jnp.concatenate(steps)
    )
    return out, runs


def residuals(u, problem: FitProblem, adjoint=None) -> jax.Array:
    """All residuals as one flat vector ($+\\infty$ for failed simulations)."""
    parts, _ = residuals_by_experiment(u, problem, adjoint)
    return jnp.concatenate([r.reshape(-1) for r in parts])


def loss(u, problem: FitProblem) -> jax.Array:
    """$\\tfrac12\\sum r^2$, differentiable in reverse mode (diffrax's default
    `RecursiveCheckpointAdjoint`)."""
    r = residuals(u, problem)
    return 0.5 * jnp.sum(r**2)


def loss_and_runs(u, problem: FitProblem) -> tuple[jax.Array, Runs]:
    """`loss` and how the simulations went (`Runs`, an auxiliary output for
    `jax.value_and_grad(..., has_aux=True)`)."""
    parts, runs = residuals_by_experiment(u, problem)
    return 0.5 * jnp.sum(jnp.stack([jnp.sum(r**2) for r in parts])), runs


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (get_num_traces)
def evaluate(u, problem: FitProblem):
    """The loss $\\tfrac12\\sum r^2$ at `u`, how its simulations went (`Runs`),
    and the residuals per batch (`residuals_by_experiment`), compiled."""
    parts, runs = residuals_by_experiment(u, problem)
    value = 0.5 * sum(jnp.sum(r**2) for r in parts)
    return value, runs, parts


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (get_num_traces)
def _sensitivities(u, problem: FitProblem) -> jax.Array:
    def fn(v):
        return residuals(v, problem, diffrax.ForwardMode())

    return jax.jacfwd(fn)(u)


def jacobian(u, problem: FitProblem) -> jax.Array:
    """$J = \\partial r/\\partial u$ by forward-mode sensitivities (`jax.jacfwd`
    through `simulate` with `diffrax.ForwardMode()`): one integration carrying one
    tangent per entry of $u$, under the options' `max_steps` rather than the step
    budget (the budget is for trial points, whose plain simulations come first),
    so that one compiled program serves the whole fit."""
    return _sensitivities(u, with_step_budget(problem, None))


def residuals_jacobian_and_runs(u, problem: FitProblem):
    """$r(u)$ (flat), $J = \\partial r/\\partial u$ (`jacobian`) and how the
    simulations went (`Runs`).

    The residuals come first, from the simulations without sensitivities
    (`evaluate`, under the step budget). Where a simulation fails ($+\\infty$
    residuals, e.g. a trial point beyond the step budget), or the loss exceeds
    `problem.jacobian_loss_limit` (a trial point that a descent method rejects
    anyway), the costly integration with sensitivities is skipped and $J$ is
    returned as zero. Two compiled programs rather than one: the one with
    sensitivities, the larger, compiles once per fit whatever the budget."""
    value, runs, parts = evaluate(u, problem)
    r = jnp.concatenate([x.reshape(-1) for x in parts])
    # Every residual is finite where the loss is (failed runs give +inf). A
    # relative margin for round-off between this sum and the solver's own.
    limit = float(problem.jacobian_loss_limit) * (1.0 + 1e-6)
    if np.isfinite(float(value)) and float(value) <= limit:
        J = jacobian(u, problem)
    else:
        J = jnp.zeros(r.shape + jnp.shape(u), jnp.float64)
    return r, J, runs


def residuals_and_jacobian(u, problem: FitProblem):
    """$r(u)$ and $J = \\partial r/\\partial u$ (`residuals_jacobian_and_runs`
    without the `Runs`)."""
    r, J, _ = residuals_jacobian_and_runs(u, problem)
    return r, J
