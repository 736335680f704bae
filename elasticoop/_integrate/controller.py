"""The step-size controller of `simulate`: diffrax's, plus a clean stop where no step
can succeed, and a record of the last accepted step for locating events (or of all
of them, for `StepwiseAdjoint`)."""

from collections.abc import Callable
from typing import Any, NamedTuple

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PyTree

from .._custom_types import Scalar
from .fused_sums import all_finite
from .recorder import AbstractStepRecorder, AcceptedSteps, StepLayout

# A step shorter than this many units in the last place of the times that gives NaN
# or inf ends the run: the vector field is not finite right after the current time.
MIN_STEP_ULPS = 16


class StepRecord(NamedTuple):
    """The state of `StopFailedSteps`: the wrapped controller's state, and what the
    run's end is explained and located with."""

    inner: Any
    # whether the last step tried held NaN or inf (its end state or its length)
    nonfinite: Bool[Array, ""]
    # the time that step tried to reach
    t_tried: Scalar
    # the last accepted step (its start, where `locate_event` interpolates from)
    steps: AcceptedSteps
    # a recording controller's: all the accepted steps, in its `StepLayout`
    history: AcceptedSteps | None
    # with a step limit: the steps tried so far, and the end of the solve
    n_tried: Int[Array, ""] | None = None
    t_final: Scalar | None = None

    @property
    def t_start(self) -> Scalar:
        """The start time of the last accepted step (the start of the run if none)."""
        return self.steps.t_start[0]

    @property
    def y_start(self) -> PyTree[Array]:
        """The state at `t_start`."""
        return jax.tree.map(lambda y: y[0], self.steps.y_start)


class StopFailedSteps(AbstractStepRecorder):
    """An adaptive step-size controller that ends the solve at once (diffrax's
    `RESULTS.dt_min_reached`) where no step can succeed. That is when a rejected
    step gave NaN or inf although it was shorter than `min_step` (or its length was
    NaN or inf itself): the vector field is not finite right after the current
    time, and shorter steps only repeat that. Or when the next step cannot advance
    time any more (the step size has collapsed on finite values). Or, from the
    first step, when `halt` is set (a start that is not simulated). Otherwise it is
    `controller`. With a `step_limit` (a traced number of steps, below the solve's
    static `max_steps`) it also ends the solve as diffrax's `max_steps` does
    (`RESULTS.max_steps_reached`) when the step tried is the `step_limit`-th and the
    solve has not reached its end: a limit that changes without compiling anew.

    Its state is a `StepRecord`: `controller`'s state, whether the last step tried
    held NaN or inf, which tells a non-finite failure from a collapse of the step
    size on finite values, the time that step tried to reach, the last accepted
    step (`AcceptedSteps` of one row), and with `recording(layout)` all of them
    in `layout` (what `StepwiseAdjoint` replays)."""

    controller: diffrax.AbstractAdaptiveStepSizeController
    # each one value, or one for each element of a batch the batch loop
    # integrates (where it depends on what is batched: the times, the model)
    min_step: Float[Array, "*times_batch"]
    halt: Bool[Array, "*start_batch"]
    # the most steps tried (None: the solve's `max_steps` only)
    step_limit: Int[Array, ""] | None
    # `controller`'s, which diffrax reads from the outermost controller
    rtol: int | float | Array | np.ndarray
    atol: int | float | Array | np.ndarray
    norm: Callable = eqx.field(static=True)
    # where the state keeps every accepted step (None: the last one only)
    layout: StepLayout | None = eqx.field(static=True)

    def __init__(
        self,
        controller: diffrax.AbstractAdaptiveStepSizeController,
        min_step: Float[Array, "*times_batch"],
        halt: Bool[Array, "*start_batch"],
        layout: StepLayout | None = None,
        step_limit: Int[Array, ""] | None = None,
    ):
        self.controller = controller
        self.min_step = min_step
        self.halt = halt
        self.step_limit = step_limit
        self.rtol = controller.rtol
        self.atol = controller.atol
        self.norm = controller.norm
        self.layout = layout

    def recording(self, layout: StepLayout) -> "StopFailedSteps":
        return StopFailedSteps(
            self.controller, self.min_step, self.halt, layout, self.step_limit
        )

    @property
    def records(self) -> bool:
        return self.layout is not None

    def accepted_steps(self, state: StepRecord) -> tuple[AcceptedSteps, StepRecord]:
        assert state.history is not None  # (a recording controller's state)
        # (the count of the last-step record: the batch loop freezes it, not the
        # history, for a sample that has finished)
        history = state.history._replace(n_accepted=state.steps.n_accepted)
        return history, state._replace(history=None)

    def with_accepted_steps(
        self, state: StepRecord, steps: AcceptedSteps | None
    ) -> StepRecord:
        return state._replace(history=steps)

    def wrap(self, direction: Any) -> "StopFailedSteps":
        controller = self.controller.wrap(direction)
        return eqx.tree_at(lambda c: c.controller, self, controller)

    def init(
        self,
        terms: Any,
        t0: Any,
        t1: Any,
        y0: PyTree,
        dt0: Any,
        args: Any,
        func: Any,
        error_order: Any,
    ) -> tuple[Any, StepRecord]:
        t_next, state = self.controller.init(
            terms, t0, t1, y0, dt0, args, func, error_order
        )
        t0 = jnp.asarray(t0)

        def slots(x, rows, fill):
            x = jnp.asarray(x)
            return jnp.full((rows, *x.shape), fill, x.dtype).at[0].set(x)

        times = slots(t0, 1, jnp.inf)
        steps = AcceptedSteps(
            jnp.array(0, jnp.int32), times, times, jax.tree.map(slots, y0, 1, 0)
        )
        history = None
        layout = self.layout
        if layout is not None:
            # (a spare row after the last, where a finished sample of the batch
            # loop writes once it has taken `max_steps` steps)
            times = slots(t0, layout.max_steps + 1, jnp.inf)
            history = AcceptedSteps(
                steps.n_accepted,
                times,
                times,
                jax.tree.map(lambda y: slots(y, layout.spare + 1, 0), y0),
            )
        n_tried = t_final = None
        if self.step_limit is not None:
            n_tried, t_final = jnp.array(0, jnp.int32), jnp.asarray(t1)
        record = StepRecord(
            state, jnp.array(False), t0, steps, history, n_tried, t_final
        )
        return t_next, record

    def adapt_step_size(
        self,
        t0: Any,
        t1: Any,
        y0: PyTree,
        y1_candidate: PyTree,
        args: Any,
        y_error: PyTree,
        error_order: Any,
        controller_state: StepRecord,
    ) -> tuple[Any, Any, Any, Any, StepRecord, Any]:
        keep, next_t0, next_t1, made_jump, state, result = (
            self.controller.adapt_step_size(
                t0, t1, y0, y1_candidate, args, y_error, error_order,
                controller_state.inner,
            )
        )  # fmt: skip
        finite = jnp.isfinite(t1) & jnp.isfinite(next_t1)
        for leaf in jax.tree.leaves(y1_candidate):
            finite = finite & all_finite(leaf)  # (a sum that XLA fuses)
        # `not >=`, `not >`: also true for NaN
        short = jnp.logical_not(t1 - t0 >= self.min_step)
        stalled = jnp.logical_not(next_t1 > next_t0)
        rejected = jnp.logical_not(keep)
        stop = self.halt | rejected & (short & ~finite | stalled)
        n_tried = controller_state.n_tried
        if self.step_limit is not None:
            assert n_tried is not None and controller_state.t_final is not None
            n_tried = n_tried + 1
            # (the end of diffrax's loop: the step kept ends at the solve's end)
            ended = keep & (next_t0 >= controller_state.t_final)
            limit = (n_tried >= self.step_limit) & ~ended
            result = diffrax.RESULTS.where(
                limit, diffrax.RESULTS.max_steps_reached, result
            )
        result = diffrax.RESULTS.where(stop, diffrax.RESULTS.dt_min_reached, result)

        # the last accepted step: a rejected one leaves it as it was
        def put_last(buffer, value):
            return jnp.where(keep, value[None], buffer)

        n_accepted = controller_state.steps.n_accepted + jnp.asarray(keep, jnp.int32)
        steps = AcceptedSteps(
            n_accepted,
            *jax.tree.map(put_last, controller_state.steps[1:], (t0, t1, y0)),
        )
        history = controller_state.history
        if self.layout is not None:
            assert history is not None
            # Every step writes the slots after the accepted ones: a rejected step
            # is tried again from the same start, and the accepted one overwrites
            # them. (A write that first reads the slot, `where(keep, new, old)`,
            # made XLA's CPU runtime hand part of each step to its thread pool,
            # a slower forward run.) The slot is the record's own count (the
            # last-step record's count made the forward half of a gradient
            # slower). In the
            # batch loop a finished sample goes on writing past its last step
            # (its count runs ahead of the frozen one): nothing reads there, and
            # past `max_steps` it writes the spare row.
            n = history.n_accepted
            max_steps = self.layout.max_steps
            slot = jnp.where(n < max_steps, n, max_steps)
            y_slot = jnp.minimum(self.layout.slot(n), self.layout.spare)
            history = AcceptedSteps(
                n_accepted,
                history.t_start.at[slot].set(t0),
                history.t_end.at[slot].set(t1),
                jax.tree.map(lambda b, y: b.at[y_slot].set(y), history.y_start, y0),
            )
        record = StepRecord(
            state, ~finite, t1, steps, history, n_tried, controller_state.t_final
        )
        return keep, next_t0, next_t1, made_jump, record, result
