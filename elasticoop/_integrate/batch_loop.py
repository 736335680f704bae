"""One loop over a whole `vmap`-ed batch: the solve of `simulate(..., batch_loop=True)`.

`integrate` (`solve.py`) hands a batched solve here through
`jax.custom_batching.custom_vmap`. Why: `vmap` of diffrax's loop runs the solver's
step under `vmap`, which costs several times the step on one batched array
(`benchmarks/loop.py`: the Tsit5 step alone). The batch loop steps the batched
state at once, each sample $b$ from its own time $t_b$ over its own step $h_b$,
with the solver's Butcher tableau (`rk_step.py`: diffrax's arithmetic, its sums
over the stages written elementwise; equal to diffrax's step to rounding).
Everything else is diffrax's, per sample (`vmap`-ed, cheap scalars): the step-size
controller's `init` and `adapt_step_size`, the solver's interpolation for the
outputs, and the loop's rules as `diffrax.diffeqsolve` applies them (the end
clipped within 100 ulps of $t_1$, the first stop condition that changes sign from
positive to non-positive ends the run at the end of that step, the first failure
kept, `max_steps`). One sample's steps never depend on the others: the first stage
of a step is reused from the step before (FSAL) or evaluated for that sample alone.
The tests compare batches with `vmap` of diffrax's loop: the same steps, statuses
and events, and states equal to within the solver's tolerance (a step's rounding,
carried through the controller's choice of the next steps: up to 5e-12 at the
default tolerances).

With `lanes` (`simulate(..., batch_loop=n)`), the loop integrates at most `lanes`
samples at once: when a sample stops while others wait, its results are stored and
the next sample waiting starts in its lane, from a start computed before the loop
(in blocks of `lanes` samples); the samples still in their lanes when none waits
are stored together after the loop (so a batch that fits its lanes, as on a GPU,
stores nothing inside the loop). A batch of samples all at once runs until its
slowest sample is done, its other lanes idle meanwhile; lanes refilled as samples
stop take few more lane steps than the samples' own steps
(`benchmarks/montecarlo.py`). Each sample's results do not depend on the
number of lanes or on the lane it ran in; they equal those of the whole batch at
once to rounding (not bitwise: the tests compare them to 1e-12).
"""

import dataclasses
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int, PyTree

from .._compat import wrapped_term
from .outcome import Outcome, results_where
from .recorder import AbstractStepRecorder, AcceptedSteps
from .rk_step import by_row, dense_weights, explicit_step, stage_buffer

RESULTS = diffrax.RESULTS


# The lanes of the batch loop by default on a CPU: wide enough for the vector
# field's arithmetic to run on whole vectors, narrow enough that few lanes idle
# (`benchmarks/vmap_default.py`, `benchmarks/montecarlo.py`).
CPU_LANES = 128


def default_lanes() -> bool | int:
    """The lanes of `simulate`'s batch loop by default: `CPU_LANES` on a CPU, and on
    an accelerator the whole batch at once (`True`), whose width it has the cores
    for."""
    return CPU_LANES if jax.default_backend() == "cpu" else True


class _Sample(eqx.Module):
    """Where each sample of the loop stands (a leading axis over the samples, or
    over the lanes)."""

    # the step to try next: from `tprev` to `tnext`
    tprev: Float[Array, " width"]
    tnext: Float[Array, " width"]
    y: PyTree[Array]
    # the first stage of the next step (FSAL; None otherwise): at the start as the
    # solver's `init` evaluates it, then the last stage of the step accepted,
    # evaluated again after a jump (`made_jump`; None where the controller never
    # jumps)
    f0: PyTree[Array] | None
    made_jump: Bool[Array, " width"] | None
    controller_state: PyTree
    # diffrax's `RESULTS` (a type checker takes its items for strings)
    result: Any
    num_steps: Int[Array, " width"]
    # the stop conditions at `tprev`, and which one ended the run
    values: tuple[Array, ...]
    mask: tuple[Bool[Array, " width"], ...]
    # the next output: its index into ts, and its slot in the outputs (ts[0] is
    # saved too, at the first step, so the two are one index)
    next_time: Int[Array, " width"]


class _Span(eqx.Module):
    """What each sample is integrated over: its output times, the time from which
    a step is stretched to the end (within 100 ulps of it, as diffrax does), the
    end, and its own arrays of the setup (those batched)."""

    ts: Float[Array, "width times"]
    clip_floor: Float[Array, " width"]
    t1: Float[Array, " width"]
    batched: PyTree


class _Finals(eqx.Module):
    """What is kept of each sample once it has stopped (of one sample, or with a
    leading axis over the samples)."""

    saved_ys: PyTree[Array]
    tprev: Float[Array, "*batch"]
    result: Any
    mask: tuple[Bool[Array, "*batch"], ...]
    controller_state: PyTree
    num_steps: Int[Array, "*batch"]
    next_time: Int[Array, "*batch"]


class _LoopState(eqx.Module):
    """The state of the batch loop: the samples in it, their outputs so far, the
    stage increments of the last step tried, and a recording controller's record
    of the steps (written in place, apart from the samples: selected with them it
    would be copied at every step). In lanes also: each lane's span and sample,
    the next sample waiting (`head`), and the results of the samples stopped."""

    samples: _Sample
    saved_ys: PyTree[Array]
    ks: PyTree[Array]
    record: AcceptedSteps | None = None
    spans: _Span | None = None
    lane_sample: Int[Array, " width"] | None = None
    head: Int[Array, ""] | None = None
    done: _Finals | None = None


def _float_before(x: Array) -> Array:
    """The float before `x` (diffrax's `t1 - 100 ulps` is 100 of these)."""
    return jnp.where(x == 0, -jnp.finfo(x.dtype).tiny, jnp.nextafter(x, -jnp.inf))


def _select(pred: Bool[Array, " batch"], new: PyTree, old: PyTree) -> PyTree:
    return jax.tree.map(lambda n, o: jnp.where(by_row(pred, n), n, o), new, old)


def _row(tree: Any, i: Any) -> Any:
    return jax.tree.map(lambda x: x[i], tree)


def _set_row(tree: Any, i: Any, value: Any) -> Any:
    return jax.tree.map(lambda x, v: x.at[i].set(v), tree, value)


def _leaf_axes(arrays: PyTree, axes: PyTree) -> list:
    """The axis (0 or None) of each leaf of `arrays`, from `axes` (a tree of 0 or
    None over the leaves of `arrays`)."""
    treedef = jax.tree.structure(arrays)
    return treedef.flatten_up_to(axes)  # type: ignore[attr-defined]


def _batched_rows(arrays: PyTree, axes: PyTree, fn: Callable) -> PyTree:
    """`arrays` with `fn(leaf)` in place of each batched leaf (axis 0 in `axes`)."""
    leaves = [
        x if a is None else fn(x)
        for x, a in zip(jax.tree.leaves(arrays), _leaf_axes(arrays, axes), strict=True)
    ]
    return jax.tree.unflatten(jax.tree.structure(arrays), leaves)


def _batch_size(arrays: PyTree, axes: PyTree) -> int:
    """The length of the batched leaves of `arrays` (axis 0 in `axes`)."""
    for x, a in zip(jax.tree.leaves(arrays), _leaf_axes(arrays, axes), strict=True):
        if a is not None:
            return x.shape[0]
    raise ValueError("a batch needs at least one batched array")


def batch_solve(
    vector_field: Callable[[Any, PyTree, Any], PyTree],
    solver: diffrax.AbstractERK,
    conditions: Sequence[Callable[[Any, PyTree, Any], Any]],
    max_steps: int,
    static: Any,
    arrays: Any,
    axes: Any,
    lanes: int | None = None,
) -> Outcome:
    """`integrate`'s solve for a batch, in one loop (the module's docstring), as an
    `Outcome` with a leading batch axis. `vector_field(t, y, args)`; `solver`: an
    explicit Runge-Kutta method with a Butcher tableau; `conditions`: the stop
    conditions, functions of $t$, $y$, `args`; `arrays` and `static`: the solve's
    setup (`y0`, `args`, `ts`, `dt0`, the step-size controller) partitioned by
    `eqx.partition`; `axes`: 0 for the leaves of `arrays` that are batched, else
    None. `lanes`: integrate at most this many samples at once, each of the others
    starting in the place of one that has stopped (the module's docstring); None:
    the whole batch at once."""

    def per_sample(fn: Callable, *sample_axes: int | None) -> Callable:
        """`fn(setup, *per-sample)` for every sample."""

        def one(arrays, *xs):
            return fn(eqx.combine(arrays, static), *xs)

        return jax.vmap(one, in_axes=(axes, *sample_axes))

    term = diffrax.ODETerm(vector_field)
    error_order = solver.error_order(term)
    field = per_sample(lambda s, t, y: vector_field(t, y, s.args), 0, 0)

    def evaluate_conditions(arrays: Any, t: Array, y: PyTree) -> tuple[Array, ...]:
        return tuple(
            per_sample(lambda s, t, y, c=c: jnp.asarray(c(t, y, s.args)), 0, 0)(
                arrays, t, y
            )
            for c in conditions
        )

    def init(s):
        t_next, state = s.controller.wrap(1).init(
            wrapped_term(term), s.ts[0], s.ts[-1], s.y0, s.dt0, s.args, solver.func,
            error_order,
        )  # fmt: skip
        # within 100 ulps of the end, a step is stretched to it (as diffrax does)
        clip_floor = s.ts[-1]
        for _ in range(100):
            clip_floor = _float_before(clip_floor)
        return s.ts, clip_floor, jnp.minimum(t_next, s.ts[-1]), state, s.y0

    tableau = solver.tableau
    assert isinstance(tableau, diffrax.ButcherTableau)  # (`integrate` checks)
    fsal = tableau.fsal  # the first stage the same as the last one

    def starts(arrays):
        """Each sample's start: its times, the controller's first step and state,
        and (FSAL) the vector field and the stop conditions at its start."""
        ts, clip_floor, tnext, controller_state, y = per_sample(init)(arrays)
        t0 = ts[:, 0]
        f0 = field(arrays, t0, y) if fsal else None
        return (
            ts,
            clip_floor,
            tnext,
            controller_state,
            y,
            f0,
            (evaluate_conditions(arrays, t0, y)),
        )

    batch = _batch_size(arrays, axes)
    queued = lanes is not None
    width = batch if lanes is None else min(lanes, batch)
    if queued:
        # in blocks of `lanes` samples, so that each sample's start is computed
        # as in a loop over `lanes` samples at once (the vector field's results
        # can depend on the width at the level of rounding)
        blocks = -(-batch // width)
        order = jnp.minimum(jnp.arange(blocks * width), batch - 1)

        def block(b):
            rows = jax.lax.dynamic_slice_in_dim(order, b * width, width)
            return starts(_batched_rows(arrays, axes, lambda x: x[rows]))

        out = jax.lax.map(block, jnp.arange(blocks))
        out = jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:])[:batch], out)
    else:
        out = starts(arrays)
    ts, clip_floor, tnext, controller_state, y, f0, values = out
    n_times = ts.shape[1]
    # A controller that records the steps (for `StepwiseAdjoint`) keeps the record
    # apart, written in place: selected with the rest of the loop's state, it
    # would be copied at every step.
    recorder = static.controller
    recording = isinstance(recorder, AbstractStepRecorder) and recorder.records
    if recording and queued:
        raise ValueError("a batch that records its steps runs all its samples at once")
    record = None
    if recording:
        record, controller_state = recorder.accepted_steps(controller_state)
    t0, t1 = ts[:, 0], ts[:, -1]
    # what each sample is integrated over, and the samples' arrays that differ
    # from one to the next (the others are the same for every sample)
    spec = jax.tree.unflatten(
        jax.tree.structure(arrays), [a is not None for a in _leaf_axes(arrays, axes)]
    )
    batched, shared = eqx.partition(arrays, spec)
    everyone = _Span(ts, clip_floor, t1, batched)

    jumps = []  # whether the controller may report a jump (see below)

    def adapt(s, tprev, tnext, y0, y1, y_error, state):
        out = s.controller.wrap(1).adapt_step_size(
            tprev, tnext, y0, y1, s.args, y_error, error_order, state
        )
        jumps.append(out[3] is not False)
        return out

    adapt = per_sample(adapt, 0, 0, 0, 0, 0, 0)
    # After a jump, the first stage of a first-same-as-last tableau is evaluated
    # again. A controller that never jumps (diffrax's `PIDController`) returns the
    # Python constant `False`: then the loop neither records jumps nor tests for
    # them at every step.
    whole_state = (
        recorder.with_accepted_steps(controller_state, record)
        if recording
        else controller_state
    )
    jax.eval_shape(adapt, arrays, t0, t0, y, y, y, whole_state)
    track_jumps = fsal and any(jumps)

    # each sample's state at its start
    start = _Sample(
        tprev=t0,
        tnext=tnext,
        y=y,
        f0=f0,
        made_jump=jnp.zeros(batch, bool) if track_jumps else None,
        controller_state=controller_state,
        result=results_where(
            jnp.ones(batch, bool), RESULTS.successful, RESULTS.successful
        ),
        num_steps=jnp.zeros(batch, jnp.int32),
        values=values,
        mask=tuple(jnp.zeros(batch, bool) for _ in conditions),
        next_time=jnp.zeros(batch, jnp.int32),
    )
    saved_ys = jax.tree.map(
        lambda x: jnp.full((width, n_times + 1, *x.shape[1:]), jnp.inf, x.dtype), y
    )
    # the stage increments (of the last step tried)
    ks = stage_buffer(tableau, _row(y, slice(0, width)))
    carry: _LoopState
    if queued:
        # The lanes start with the first `lanes` samples
        lanes_now = slice(0, width)
        carry = _LoopState(
            samples=_row(start, lanes_now),
            saved_ys=saved_ys,
            ks=ks,
            record=None,
            spans=_row(everyone, lanes_now),
            lane_sample=jnp.arange(width),
            head=jnp.asarray(width),
            done=_Finals(
                saved_ys=jax.tree.map(
                    lambda x: jnp.full(
                        (batch, n_times + 1, *x.shape[1:]), jnp.inf, x.dtype
                    ),
                    y,
                ),
                tprev=t0,
                result=start.result,
                mask=start.mask,
                controller_state=controller_state,
                num_steps=start.num_steps,
                next_time=start.next_time,
            ),
        )
    else:
        carry = _LoopState(start, saved_ys, ks, record)
    rows = jnp.arange(width)

    def span_of(c: _LoopState) -> tuple[_Span, PyTree]:
        """What the samples in the loop are integrated over, and their setup."""
        if c.spans is None:
            return everyone, arrays
        return c.spans, eqx.combine(c.spans.batched, shared)

    def full_state(c: _LoopState) -> PyTree:
        """The controller's state, its record of the steps put back."""
        if recording:
            return recorder.with_accepted_steps(c.samples.controller_state, c.record)
        return c.samples.controller_state

    def unfinished(c: _LoopState) -> Bool[Array, " width"]:
        s = c.samples
        return (s.tprev < span_of(c)[0].t1) & (s.result == RESULTS.successful)

    def running(c: _LoopState) -> Bool[Array, " width"]:
        return unfinished(c) & (c.samples.num_steps < max_steps)

    def body(c: _LoopState) -> _LoopState:
        span, arrays = span_of(c)
        s = c.samples
        active = running(c)
        f0 = s.f0
        if track_jumps:
            assert s.made_jump is not None
            redo = s.made_jump & active
            f0 = jax.lax.cond(
                jnp.any(redo),
                lambda: _select(redo, field(arrays, s.tprev, s.y), f0),
                lambda: f0,
            )
        y1, y_error, ks, f_last, _ = explicit_step(
            tableau,
            partial(field, arrays),
            s.tprev,
            s.tnext,
            s.y,
            f0,  # None where the tableau is not first-same-as-last
            c.ks,
        )
        y_error = jax.tree.map(lambda x: jnp.where(jnp.isnan(x), jnp.inf, x), y_error)
        keep, tprev, tnext, made_jump, controller_state, result = adapt(
            arrays, s.tprev, s.tnext, s.y, y1, y_error, full_state(c)
        )
        record = c.record
        if recording:
            # (a finished sample writes its record past its last step: unread)
            record, controller_state = recorder.accepted_steps(controller_state)
        tprev = jnp.minimum(tprev, span.t1)
        tnext = jnp.where(
            tnext > span.clip_floor,
            jnp.where(keep, span.t1, tprev + 0.5 * (span.t1 - tprev)),
            tnext,
        )
        y = _select(keep, y1, s.y)
        if fsal:
            f0 = _select(keep, f_last, f0)
        if track_jumps:
            assert s.made_jump is not None
            made_jump = jnp.where(keep, made_jump, s.made_jump)
        else:
            made_jump = None
        result = results_where(s.result == RESULTS.successful, result, s.result)
        # the outputs are written only where a step was accepted
        next_time, saved_ys = _save_outputs(
            solver,
            dict(y0=s.y, y1=y1, k=ks),
            (s.tprev, s.tnext),
            (s.next_time, c.saved_ys),
            active & keep,
            span.ts,
            rows,
            n_times,
        )
        values = evaluate_conditions(arrays, tprev, y)
        mask, had_event = [], jnp.zeros(width, bool)
        for old, new in zip(s.values, values, strict=True):
            hit = (jnp.sign(old) > 0) & (jnp.sign(new) <= 0)
            mask.append(hit & ~had_event)
            had_event = had_event | hit
        stepped = _Sample(
            tprev=tprev,
            tnext=tnext,
            y=y,
            f0=f0,
            made_jump=made_jump,
            controller_state=controller_state,
            result=results_where(had_event, RESULTS.event_occurred, result),
            num_steps=s.num_steps + 1,
            values=values,
            mask=tuple(mask),
            next_time=next_time,
        )
        # the stage increments are those of the step just tried (written before
        # read), the record is written in place
        c = dataclasses.replace(
            c,
            samples=_select(active, stepped, s),
            saved_ys=saved_ys,
            ks=ks,
            record=record,
        )
        return refill(c) if queued else c

    def with_end_state(saved_ys: PyTree, slot: Array, y: PyTree) -> PyTree:
        """The outputs with the end state after them (diffrax's SaveAt(t1=True))."""
        return jax.tree.map(
            lambda b, v: b.at[rows, slot].set(v, mode="drop"), saved_ys, y
        )

    def retire_and_start(c: _LoopState) -> _LoopState:
        """The first lane whose sample has stopped: the sample's results stored,
        and the next sample waiting started in its place."""
        assert c.lane_sample is not None and c.head is not None
        assert c.done is not None and c.spans is not None
        lane = jnp.argmax(~running(c))
        s = c.samples
        end = jax.tree.map(
            lambda b, v: b[lane].at[s.next_time[lane]].set(v[lane], mode="drop"),
            c.saved_ys,
            s.y,
        )
        result = RESULTS.where(
            unfinished(c)[lane], RESULTS.max_steps_reached, _row(s.result, lane)
        )
        finals = _Finals(
            saved_ys=end,
            tprev=s.tprev[lane],
            result=result,
            mask=_row(s.mask, lane),
            controller_state=_row(s.controller_state, lane),
            num_steps=s.num_steps[lane],
            next_time=s.next_time[lane],
        )
        following = c.head
        return dataclasses.replace(
            c,
            samples=_set_row(s, lane, _row(start, following)),
            spans=_set_row(c.spans, lane, _row(everyone, following)),
            saved_ys=jax.tree.map(lambda b: b.at[lane].set(jnp.inf), c.saved_ys),
            done=_set_row(c.done, c.lane_sample[lane], finals),
            lane_sample=c.lane_sample.at[lane].set(following),
            head=following + 1,
        )

    def refill(c: _LoopState) -> _LoopState:
        """Every lane whose sample has stopped, while samples are waiting."""

        def waiting(c):
            return jnp.any(~running(c)) & (c.head < batch)

        return jax.lax.while_loop(waiting, retire_and_start, c)

    def retire_all(c: _LoopState) -> _Finals:
        """The results of the samples still in their lanes (stopped once no
        sample waits, and kept there), stored at once."""
        s = c.samples
        finals = _Finals(
            saved_ys=with_end_state(c.saved_ys, s.next_time, s.y),
            tprev=s.tprev,
            result=results_where(unfinished(c), RESULTS.max_steps_reached, s.result),
            mask=s.mask,
            controller_state=s.controller_state,
            num_steps=s.num_steps,
            next_time=s.next_time,
        )
        assert c.done is not None
        return _set_row(c.done, c.lane_sample, finals)

    if queued:
        carry = refill(carry)
    c = jax.lax.while_loop(lambda c: jnp.any(running(c)), body, carry)
    if queued:
        done = retire_all(c)
    else:
        s = c.samples
        done = _Finals(
            saved_ys=with_end_state(c.saved_ys, s.next_time, s.y),
            tprev=s.tprev,
            result=results_where(unfinished(c), RESULTS.max_steps_reached, s.result),
            mask=s.mask,
            controller_state=full_state(c),
            num_steps=s.num_steps,
            next_time=s.next_time,
        )
    slot, tprev = done.next_time, done.tprev
    slots = jnp.arange(n_times + 1, dtype=slot.dtype)[None, :]
    saved_ts = jnp.concatenate([ts, jnp.full((batch, 1), jnp.inf, ts.dtype)], 1)
    saved_ts = jnp.where(slots < slot[:, None], saved_ts, jnp.inf)
    saved_ts = jnp.where(slots == slot[:, None], tprev[:, None], saved_ts)
    return Outcome(
        saved_ts, done.saved_ys, done.result, done.mask, done.controller_state,
        done.num_steps,
    )  # fmt: skip


def _interpolation(
    solver: diffrax.AbstractSolver, dense: dict[str, PyTree[Array]]
) -> Callable:
    """`evaluate(dense, t0, t1, t)`: the solver's dense output of each sample's step
    from `t0` to `t1`, at its own `t`; `dense`: the step's `y0`, `y1` and stage
    increments `k`.

    The interpolants of diffrax's Runge-Kutta solvers are linear in the step's
    $y_0$, $y_1$ and stage increments $k_i = h f_i$:
    $y(t) = c_0 y_0 + c_1 y_1 + \\sum_i c_{2+i} k_i$. The coefficients $c$ of each
    sample are the gradient of the interpolant with respect to $y_0$, $y_1$ and the
    $k_i$ (`dense_weights`, `vmap`-ed over the samples, a few numbers each), and the
    sum runs on the whole batch: `vmap` of the interpolant itself contracts each
    sample's stages on its own, slower in `benchmarks/loop.py`'s batch loop. (The
    interpolant of the unit vectors gives the same coefficients, but through a dot
    product with the identity, which XLA's CPU backend hands to a matrix kernel,
    where the gradient's products fuse.)"""
    stages = jax.tree.leaves(dense["k"])[0].shape[0]
    dtype = jax.tree.leaves(dense["y0"])[0].dtype

    def coefficients(t0, t1, t):
        c = dense_weights(solver, t0, t1, t)
        return tuple(c[i] for i in range(2 + stages))

    # The terms whose coefficient is zero wherever the interpolant is evaluated
    # (Dopri8's $y_1$ and $k_2, ..., k_5$; Tsit5's $y_1$): each coefficient is a
    # polynomial in $t$, taken as zero where it is zero at three points inside a
    # step. They are left out of the sum (they added +0).
    with jax.ensure_compile_time_eval():
        used = np.zeros(2 + stages, bool)
        for t in (0.3, 0.5719, 0.8837):
            c = coefficients(jnp.zeros((), dtype), jnp.ones((), dtype), t)
            used |= np.array([float(x) != 0 for x in c])

    def evaluate(info, t0, t1, t):
        c = jax.vmap(coefficients)(t0, t1, t)  # 2 + stages arrays (batch,)

        def combine(y0, y1, k):
            terms = [(c[0], y0), (c[1], y1), *((c[2 + i], k[i]) for i in range(stages))]
            terms = [term for term, u in zip(terms, used, strict=True) if u]
            y = by_row(terms[0][0], terms[0][1]) * terms[0][1]
            for ci, x in terms[1:]:
                y = y + by_row(ci, x) * x
            return y

        return jax.tree.map(combine, info["y0"], info["y1"], info["k"])

    return evaluate


def _save_outputs(
    solver: diffrax.AbstractSolver,
    dense: dict[str, PyTree[Array]],
    step: tuple[Float[Array, " width"], Float[Array, " width"]],
    saves: tuple[Int[Array, " width"], PyTree[Array]],
    accepted: Bool[Array, " width"],
    ts: Float[Array, "width times"],
    rows: Int[Array, " width"],
    n_times: int,
) -> tuple[Int[Array, " width"], PyTree[Array]]:
    """The output times inside the step just accepted (`step`: each sample's start
    and end), from the solver's dense output, written sample by sample (diffrax's
    `SaveAt(ts)`) into `saves`: each sample's next output and the outputs."""
    evaluate = _interpolation(solver, dense)
    t_start, t_end = step

    def due(state):
        index = state[0]
        t = jnp.take_along_axis(ts, jnp.minimum(index, n_times - 1)[:, None], 1)[:, 0]
        return accepted & (index < n_times) & (t <= t_end), t

    def save(state):
        index, saved_ys = state
        now, t = due(state)
        y = evaluate(dense, t_start, t_end, t)
        slot_now = jnp.where(now, index, n_times + 1)  # out of range: not written
        saved_ys = jax.tree.map(
            lambda b, v: b.at[rows, slot_now].set(v, mode="drop"), saved_ys, y
        )
        return index + now.astype(index.dtype), saved_ys

    def pending(state):
        return jnp.any(due(state)[0])

    return jax.lax.while_loop(pending, save, saves)
