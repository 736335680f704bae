"""The solve of `simulate`: `diffrax.diffeqsolve`, or one loop over a whole batch.

`integrate` runs `diffrax.diffeqsolve` with the setup `simulate` uses (an adaptive
step-size controller, output times `ts` plus the final state, stop conditions
without a root finder, the controller's final state). Asked for `batch_loop`, it
keeps doing so on one run, but when `jax.vmap` batches it, it integrates the whole
batch in one loop instead of `vmap`-ing diffrax's (`jax.custom_batching.custom_vmap`;
the loop and why: `batch_loop.py`).

With `StepwiseAdjoint` the batch loop is the forward solve and the adjoint
(`adjoint.py`) differentiates it in reverse mode (its forward half under `vmap`
runs in the batch loop too, all samples at once). With a diffrax adjoint the batch
loop is not differentiable (forward or reverse mode): there it is for forward runs
of batches only. Explicit Runge-Kutta solvers only; with another solver, or with a
progress meter, `batch_loop` falls back on `vmap` of diffrax.
"""

from collections.abc import Callable, Sequence
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float, PyTree

from .._custom_types import Scalar
from .adjoint import StepwiseAdjoint, check_solver, stepwise_solve
from .batch_loop import batch_solve
from .outcome import Outcome
from .recorder import AbstractStepRecorder, AcceptedSteps


class _Setup(eqx.Module):
    """The inputs of a solve that may be traced (and batched)."""

    y0: PyTree[Array]
    args: Any
    ts: Float[Array, " times"]
    dt0: Scalar | float | None
    controller: diffrax.AbstractAdaptiveStepSizeController


def integrate(
    vector_field: Callable,
    solver: diffrax.AbstractSolver,
    y0: PyTree[Array],
    args: Any,
    ts: Float[Array, " times"],
    controller: diffrax.AbstractAdaptiveStepSizeController,
    conditions: Sequence[Callable[[Scalar, PyTree[Array], Any], Scalar]],
    max_steps: int,
    *,
    dt0: Scalar | float | None = None,
    adjoint: diffrax.AbstractAdjoint | StepwiseAdjoint = (
        diffrax.RecursiveCheckpointAdjoint()
    ),
    progress_meter: diffrax.AbstractProgressMeter = diffrax.NoProgressMeter(),
    batch_loop: bool | int = False,
    fallback: bool = False,
) -> Outcome:
    """Integrate $dy/dt = $ `vector_field(t, y, args)` from `ts[0]` to `ts[-1]`,
    saving at `ts` and at the end, stopping where one of `conditions` (functions of
    $t$, $y$, `args`) falls from positive to non-positive (at the end of that
    step). `batch_loop`: under `jax.vmap`, one loop for the batch (see the module's
    docstring); an integer: at most that many samples at once, the others each
    starting as one stops. `fallback`: with `StepwiseAdjoint`, a gradient with
    respect to what it does not differentiate (output times, `dt0`, the
    controller) is taken by diffrax's `RecursiveCheckpointAdjoint` instead of
    refused."""
    if isinstance(adjoint, StepwiseAdjoint):
        check_solver(solver)
        if not isinstance(controller, AbstractStepRecorder):
            raise TypeError(
                f"StepwiseAdjoint needs a controller that records the accepted steps "
                f"(an AbstractStepRecorder), got {type(controller).__name__}"
            )
    setup = _Setup(y0, args, ts, dt0, controller)
    arrays, static = eqx.partition(setup, eqx.is_array)

    event = None
    if conditions:
        event = diffrax.Event([_of_diffrax(c) for c in conditions], direction=False)

    def run(
        arrays: Any, keep_steps: bool = False
    ) -> tuple[Outcome, AcceptedSteps | None]:
        """The solve, and with `keep_steps` its `AcceptedSteps` (for
        `StepwiseAdjoint`, kept by the controller), else `None`."""
        setup = eqx.combine(arrays, static)
        controller = setup.controller
        if keep_steps:
            assert isinstance(controller, AbstractStepRecorder)  # (checked above)
            assert isinstance(adjoint, StepwiseAdjoint)
            controller = controller.recording(adjoint.layout(max_steps))
        sol = diffrax.diffeqsolve(
            diffrax.ODETerm(vector_field),
            solver,
            t0=setup.ts[0],
            t1=setup.ts[-1],
            dt0=setup.dt0,
            y0=setup.y0,
            args=setup.args,
            saveat=diffrax.SaveAt(ts=setup.ts, t1=True, controller_state=True),
            stepsize_controller=controller,
            adjoint=diffrax.RecursiveCheckpointAdjoint()
            if isinstance(adjoint, StepwiseAdjoint)
            else adjoint,
            event=event,
            max_steps=max_steps,
            throw=False,
            progress_meter=progress_meter,
        )
        state, steps = sol.controller_state, None
        if keep_steps:
            assert isinstance(controller, AbstractStepRecorder)
            steps, state = controller.accepted_steps(state)
        outcome = Outcome(
            sol.ts,
            sol.ys,
            sol.result,
            () if event is None else tuple(sol.event_mask),
            state,
            jnp.asarray(sol.stats["num_steps"], jnp.int32),
        )
        return outcome, steps

    batchable = (
        isinstance(solver, diffrax.AbstractERK)
        and isinstance(solver.tableau, diffrax.ButcherTableau)
        and isinstance(progress_meter, diffrax.NoProgressMeter)
    )

    def run_batch(arrays: Any, batched: Any) -> tuple[Outcome, AcceptedSteps]:
        """`run(arrays, keep_steps=True)` of a batch (`batched`: whether each leaf
        of `arrays` is), in the batch loop (for `StepwiseAdjoint` under `vmap`:
        the loop writes the record of the steps in place, where `vmap` of
        diffrax's loop copies it at each step)."""
        assert isinstance(adjoint, StepwiseAdjoint)
        assert isinstance(solver, diffrax.AbstractERK)  # (`batchable`)
        setup = eqx.combine(arrays, static)
        recorder = setup.controller.recording(adjoint.layout(max_steps))
        recording = eqx.tree_at(lambda s: s.controller, setup, recorder)
        # (the same leaves, under the recording controller's static fields)
        arrays, recording_static = eqx.partition(recording, eqx.is_array)
        axes = [0 if b else None for b in jax.tree.leaves(batched)]
        axes = jax.tree.unflatten(jax.tree.structure(arrays), axes)
        out = batch_solve(
            vector_field, solver, conditions, max_steps, recording_static, arrays, axes
        )
        steps, state = recorder.accepted_steps(out.controller_state)
        return eqx.tree_at(lambda o: o.controller_state, out, state), steps

    batchable_loop = bool(batch_loop) and batchable
    lanes = None if isinstance(batch_loop, bool) else int(batch_loop)

    def forward(arrays: Any) -> Outcome:
        """The solve where nothing is differentiated."""
        return run(arrays)[0]

    primal: Callable[[Any], Outcome] = forward
    if batchable_loop:
        looped = jax.custom_batching.custom_vmap(forward)
        primal = looped

        @looped.def_vmap
        def _batched(axis_size, in_batched, arrays):
            (batched,) = in_batched
            axes = jax.tree.map(lambda b: 0 if b else None, batched)
            assert isinstance(solver, diffrax.AbstractERK)  # (`batchable`)
            out = batch_solve(
                vector_field, solver, conditions, max_steps, static, arrays, axes, lanes
            )
            return out, jax.tree.map(lambda _: True, out)

    if isinstance(adjoint, StepwiseAdjoint):
        # The batch loop runs the forward solve; the adjoint differentiates it.
        assert isinstance(solver, diffrax.AbstractERK)  # (`check_solver`)
        return stepwise_solve(
            run,
            vector_field,
            solver,
            adjoint.layout(max_steps),
            static,
            arrays,
            run_batch if batchable else None,
            forward=primal,
            fallback=_fallback(run) if fallback else None,
        )
    if not batchable_loop:
        return forward(arrays)

    # JAX cannot differentiate `custom_vmap`: say so in the user's terms.
    solve = jax.custom_jvp(primal)

    @solve.defjvp
    def _no_derivative(primals, tangents):
        raise ValueError(
            "simulate(..., batch_loop=...) with a diffrax adjoint is not "
            "differentiable (forward or reverse mode); differentiate with "
            "batch_loop=False, or with the default adjoint (reverse mode)"
        )

    return solve(arrays)


def _fallback(run: Callable) -> Callable:
    """The cotangents of a solve's inputs by diffrax's
    `RecursiveCheckpointAdjoint` (which `run` uses), for gradients the stepwise
    adjoint does not take."""

    def cotangents(arrays: Any, grad_outcome: Any) -> Any:
        ys, pullback = eqx.filter_vjp(lambda a: run(a)[0].ys, arrays)
        ys_bar = grad_outcome.ys
        if ys_bar is None:
            ys_bar = jax.tree.map(jnp.zeros_like, ys)
        (grads,) = pullback(ys_bar)
        return grads

    return cotangents


def _of_diffrax(condition: Callable) -> Callable:
    def cond_fn(t: Any, y: PyTree, args: Any, **_: Any) -> Any:
        return condition(t, y, args)

    return cond_fn
