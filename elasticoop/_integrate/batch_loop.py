"""One loop over a whole `vmap`-ed batch: the solve of `simulate(..., batch_loop=True)`.

`integrate` (`solve.py`) hands a batched solve here through
`jax.custom_batching.custom_vmap`. Why: `vmap` of diffrax's loop runs the solver's
step under `vmap`, which costs about three times the step on one batched array
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
slowest sample is done, its other lanes idle meanwhile: for the 1024 samples of
`benchmarks/montecarlo.py` (Dopri8, rtol 1e-9) in batches of 128, 15 % more lane
steps than the samples' own steps. Each sample's results do not depend on the
number of lanes or on the lane it ran in; they equal those of the whole batch at
once to rounding (not bitwise: the tests compare them to 1e-12).
"""

from collections.abc import Callable
from functools import partial

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, PyTree

from .outcome import EVENT_OCCURRED, MAX_STEPS_REACHED, SUCCESSFUL, Outcome
from .recorder import AbstractStepRecorder
from .rk_step import by_row, explicit_step, stage_buffer


class _Wrapped(diffrax.AbstractTerm):
    """`term` as `diffrax.diffeqsolve` hands it to the step-size controller's
    `init`: wrapped (diffrax wraps every term in its time direction), so that the
    controller picks the same first step as there (diffrax 0.7 estimates one for an
    `ODETerm` only, and tries 0.01 for any other term). The tests compare the
    steps of a batch with single runs."""

    term: diffrax.AbstractTerm

    def vf(self, t, y, args):
        return self.term.vf(t, y, args)

    def contr(self, t0, t1, **kwargs):
        return self.term.contr(t0, t1, **kwargs)

    def prod(self, vf, control):
        return self.term.prod(vf, control)


def _float_before(x: Array) -> Array:
    """The float before `x` (diffrax's `t1 - 100 ulps` is 100 of these)."""
    return jnp.where(x == 0, -jnp.finfo(x.dtype).tiny, jnp.nextafter(x, -jnp.inf))


def _select(pred: Bool[Array, " batch"], new: PyTree, old: PyTree) -> PyTree:
    return jax.tree.map(lambda n, o: jnp.where(by_row(pred, n), n, o), new, old)


def _row(tree: PyTree, i) -> PyTree:
    return jax.tree.map(lambda x: x[i], tree)


def _set_row(tree: PyTree, i, value: PyTree) -> PyTree:
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
    vector_field, solver, conditions, max_steps, static, arrays, axes, lanes=None
):
    """`integrate`'s solve for a batch, in one loop (the module's docstring), as an
    `Outcome` with a leading batch axis. `vector_field(t, y, args)`; `solver`: an
    explicit Runge-Kutta method with a Butcher tableau; `conditions`: the stop
    conditions, functions of $t$, $y$, `args`; `arrays` and `static`: the solve's
    setup (`y0`, `args`, `ts`, `dt0`, the step-size controller) partitioned by
    `eqx.partition`; `axes`: 0 for the leaves of `arrays` that are batched, else
    None. `lanes`: integrate at most this many samples at once, each of the others
    starting in the place of one that has stopped (the module's docstring); None:
    the whole batch at once."""

    def per_sample(fn, *sample_axes):
        """`fn(setup, *per-sample)` for every sample."""

        def one(arrays, *xs):
            return fn(eqx.combine(arrays, static), *xs)

        return jax.vmap(one, in_axes=(axes, *sample_axes))

    term = diffrax.ODETerm(vector_field)
    error_order = solver.error_order(term)
    field = per_sample(lambda s, t, y: vector_field(t, y, s.args), 0, 0)

    def evaluate_conditions(arrays, t, y):
        return tuple(
            per_sample(lambda s, t, y, c=c: jnp.asarray(c(t, y, s.args)), 0, 0)(
                arrays, t, y
            )
            for c in conditions
        )

    def init(s):
        t_next, state = s.controller.wrap(1).init(
            _Wrapped(term), s.ts[0], s.ts[-1], s.y0, s.dt0, s.args, solver.func,
            error_order,
        )  # fmt: skip
        # within 100 ulps of the end, a step is stretched to it (as diffrax does)
        clip_floor = s.ts[-1]
        for _ in range(100):
            clip_floor = _float_before(clip_floor)
        return s.ts, clip_floor, jnp.minimum(t_next, s.ts[-1]), state, s.y0

    tableau = solver.tableau
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
    width = min(lanes, batch) if queued else batch
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
    # each sample's state at its start
    start = dict(
        tprev=t0,
        tnext=tnext,
        y=y,
        # the first stage of the next step (FSAL): at the start as the solver's
        # `init` evaluates it, then the last stage of the step accepted, evaluated
        # again after a jump
        f0=f0,
        made_jump=jnp.zeros(batch, bool),
        controller_state=controller_state,
        result=jnp.full(batch, SUCCESSFUL, jnp.int32),
        num_steps=jnp.zeros(batch, jnp.int32),
        values=values,
        mask=tuple(jnp.zeros(batch, bool) for _ in conditions),
        # the next output: its index into ts, and its slot in the outputs (ts[0]
        # is saved too, at the first step, so the two are one index). The times
        # of the outputs saved are those of ts: filled in after the loop
        next_time=jnp.zeros(batch, jnp.int32),
    )
    # what each sample is integrated with: its times and setup
    setup = dict(ts=ts, clip_floor=clip_floor, t1=t1, arrays=arrays)
    carry = dict(start)
    # the batched arrays of the setup, and the others (the same for every sample)
    spec = jax.tree.unflatten(
        jax.tree.structure(arrays), [a is not None for a in _leaf_axes(arrays, axes)]
    )
    batched, shared = eqx.partition(arrays, spec)
    if queued:
        # The lanes start with the first `lanes` samples; `sample`: the sample in
        # each lane; `head`: the next sample waiting
        carry = _row(carry, slice(0, width))
        carry["setup"] = _row(
            dict(ts=ts, clip_floor=clip_floor, t1=t1, batched=batched),
            slice(0, width),
        )
        carry["sample"] = jnp.arange(width)
        carry["head"] = jnp.asarray(width)
        # each sample's results, written as it stops
        carry["done"] = dict(
            saved_ys=jax.tree.map(
                lambda x: jnp.full(
                    (batch, n_times + 1, *x.shape[1:]), jnp.inf, x.dtype
                ),
                y,
            ),
            tprev=t0,
            result=start["result"],
            mask=start["mask"],
            controller_state=controller_state,
            num_steps=start["num_steps"],
            next_time=start["next_time"],
        )
    carry["saved_ys"] = jax.tree.map(
        lambda x: jnp.full((width, n_times + 1, *x.shape[1:]), jnp.inf, x.dtype), y
    )
    # the stage increments (of the last step tried)
    carry["ks"] = stage_buffer(tableau, _row(y, slice(0, width)))
    if recording:
        carry["record"] = record
    rows = jnp.arange(width)

    def setup_of(c):
        if not queued:
            return setup
        lane = dict(c["setup"])
        return lane | dict(arrays=eqx.combine(lane.pop("batched"), shared))

    def full_state(c):
        """The controller's state, its record of the steps put back."""
        if recording:
            return recorder.with_accepted_steps(c["controller_state"], c["record"])
        return c["controller_state"]

    def unfinished(c):
        return (c["tprev"] < setup_of(c)["t1"]) & (c["result"] == SUCCESSFUL)

    def running(c):
        return unfinished(c) & (c["num_steps"] < max_steps)

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
    if not track_jumps:
        carry["made_jump"] = None

    def body(c):
        setup = setup_of(c)
        arrays, ts, t1 = setup["arrays"], setup["ts"], setup["t1"]
        active = running(c)
        f0 = c["f0"]
        if track_jumps:
            redo = c["made_jump"] & active
            f0 = jax.lax.cond(
                jnp.any(redo),
                lambda: _select(redo, field(arrays, c["tprev"], c["y"]), f0),
                lambda: f0,
            )
        y1, y_error, ks, f_last = explicit_step(
            tableau,
            partial(field, arrays),
            c["tprev"],
            c["tnext"],
            c["y"],
            f0,  # None where the tableau is not first-same-as-last
            c["ks"],
        )
        y_error = jax.tree.map(lambda x: jnp.where(jnp.isnan(x), jnp.inf, x), y_error)
        keep, tprev, tnext, made_jump, controller_state, result = adapt(
            arrays, c["tprev"], c["tnext"], c["y"], y1, y_error, full_state(c)
        )
        if recording:
            # (a finished sample writes its record past its last step: unread)
            record, controller_state = recorder.accepted_steps(controller_state)
        tprev = jnp.minimum(tprev, t1)
        tnext = jnp.where(
            tnext > setup["clip_floor"],
            jnp.where(keep, t1, tprev + 0.5 * (t1 - tprev)),
            tnext,
        )
        y = _select(keep, y1, c["y"])
        if fsal:
            f0 = _select(keep, f_last, f0)
        if track_jumps:
            made_jump = jnp.where(keep, made_jump, c["made_jump"])
        else:
            made_jump = None
        result = jnp.where(c["result"] == SUCCESSFUL, result._value, c["result"])
        dense = dict(y0=c["y"], y1=y1, k=ks)
        outputs = _save_outputs(solver, dense, c, active & keep, ts, rows, n_times)
        values = evaluate_conditions(arrays, tprev, y)
        mask, had_event = [], jnp.zeros(width, bool)
        for old, new in zip(c["values"], values, strict=True):
            hit = (jnp.sign(old) > 0) & (jnp.sign(new) <= 0)
            mask.append(hit & ~had_event)
            had_event = had_event | hit
        new = dict(
            tprev=tprev,
            tnext=tnext,
            y=y,
            f0=f0,
            made_jump=made_jump,
            controller_state=controller_state,
            result=jnp.where(had_event, EVENT_OCCURRED, result),
            num_steps=c["num_steps"] + 1,
            values=values,
            mask=tuple(mask),
        )
        # the outputs are written only where a step was accepted; the stage
        # increments are those of the step just tried (written before read)
        written = outputs | dict(ks=ks)
        if recording:
            written["record"] = record
        frozen = {k: v for k, v in c.items() if k not in written and k not in new}
        c = _select(active, new, {k: c[k] for k in new}) | frozen | written
        return refill(c) if queued else c

    def with_end_state(saved_ys, slot, y):
        """The outputs with the end state after them (diffrax's SaveAt(t1=True))."""
        return jax.tree.map(
            lambda b, v: b.at[rows, slot].set(v, mode="drop"), saved_ys, y
        )

    def retire_and_start(c):
        """The first lane whose sample has stopped: the sample's results stored,
        and the next sample waiting started in its place."""
        lane = jnp.argmax(~running(c))
        sample = c["sample"][lane]
        end = jax.tree.map(
            lambda b, v: b[lane].at[c["next_time"][lane]].set(v[lane], mode="drop"),
            c["saved_ys"],
            c["y"],
        )
        result = c["result"][lane]
        result = jnp.where(unfinished(c)[lane], MAX_STEPS_REACHED, result)
        finals = dict(
            saved_ys=end,
            tprev=c["tprev"][lane],
            result=result,
            mask=_row(c["mask"], lane),
            controller_state=_row(c["controller_state"], lane),
            num_steps=c["num_steps"][lane],
            next_time=c["next_time"][lane],
        )
        done = _set_row(c["done"], sample, finals)
        following = c["head"]
        state = {k: c[k] for k in start if c[k] is not None}
        begin = _row({k: start[k] for k in state}, following)
        state = _set_row(state, lane, begin)
        lane_setup = dict(ts=ts, clip_floor=clip_floor, t1=t1, batched=batched)
        setup = _set_row(c["setup"], lane, _row(lane_setup, following))
        saved_ys = jax.tree.map(lambda b: b.at[lane].set(jnp.inf), c["saved_ys"])
        return (
            c
            | state
            | dict(
                setup=setup,
                saved_ys=saved_ys,
                done=done,
                sample=c["sample"].at[lane].set(following),
                head=following + 1,
            )
        )

    def refill(c):
        """Every lane whose sample has stopped, while samples are waiting."""

        def waiting(c):
            return jnp.any(~running(c)) & (c["head"] < batch)

        return jax.lax.while_loop(waiting, retire_and_start, c)

    def retire_all(c):
        """The results of the samples still in their lanes (stopped once no
        sample waits, and kept there), stored at once."""
        finals = dict(
            saved_ys=with_end_state(c["saved_ys"], c["next_time"], c["y"]),
            tprev=c["tprev"],
            result=jnp.where(unfinished(c), MAX_STEPS_REACHED, c["result"]),
            mask=c["mask"],
            controller_state=c["controller_state"],
            num_steps=c["num_steps"],
            next_time=c["next_time"],
        )
        return _set_row(c["done"], c["sample"], finals)

    if queued:
        carry = refill(carry)
    c = jax.lax.while_loop(lambda c: jnp.any(running(c)), body, carry)
    if queued:
        done = retire_all(c)
        slot, tprev, saved_ys = done["next_time"], done["tprev"], done["saved_ys"]
        result, mask, state = done["result"], done["mask"], done["controller_state"]
        num_steps = done["num_steps"]
    else:
        result = jnp.where(unfinished(c), MAX_STEPS_REACHED, c["result"])
        slot, tprev, mask, num_steps = (
            c["next_time"],
            c["tprev"],
            c["mask"],
            c["num_steps"],
        )
        saved_ys = with_end_state(c["saved_ys"], slot, c["y"])
        state = full_state(c)
    slots = jnp.arange(n_times + 1, dtype=slot.dtype)[None, :]
    saved_ts = jnp.concatenate([ts, jnp.full((batch, 1), jnp.inf, ts.dtype)], 1)
    saved_ts = jnp.where(slots < slot[:, None], saved_ts, jnp.inf)
    saved_ts = jnp.where(slots == slot[:, None], tprev[:, None], saved_ts)
    return Outcome(saved_ts, saved_ys, result, mask, state, num_steps)


def _interpolation(solver, dense) -> Callable:
    """`evaluate(dense, t0, t1, t)`: the solver's dense output of each sample's step
    from `t0` to `t1`, at its own `t`; `dense`: the step's `y0`, `y1` and stage
    increments `k`.

    The interpolants of diffrax's Runge-Kutta solvers are linear in the step's
    $y_0$, $y_1$ and stage increments $k_i = h f_i$:
    $y(t) = c_0 y_0 + c_1 y_1 + \\sum_i c_{2+i} k_i$. The coefficients $c$ of each
    sample are the gradient of the interpolant with respect to $y_0$, $y_1$ and the
    $k_i$ (`vmap`-ed over the samples, a few numbers each), and the sum runs on the
    whole batch: `vmap` of the interpolant itself contracts each sample's stages on
    its own, three times slower in `benchmarks/loop.py`'s batch loop. (The
    interpolant of the unit vectors gives the same coefficients, but through a
    dot product with the identity, which XLA's CPU backend hands to a matrix
    kernel: about 7 us of each save of 128 samples, where the gradient's products
    fuse.)"""
    stages = jax.tree.leaves(dense["k"])[0].shape[0]
    dtype = jax.tree.leaves(dense["y0"])[0].dtype

    def coefficients(t0, t1, t):
        def value(basis):
            return solver.interpolation_cls(t0=t0, t1=t1, **basis).evaluate(t)

        zero = jnp.zeros((), dtype)
        c = jax.grad(value)(dict(y0=zero, y1=zero, k=jnp.zeros(stages, dtype)))
        return (c["y0"], c["y1"], *(c["k"][i] for i in range(stages)))

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


def _save_outputs(solver, dense, c, accepted, ts, rows, n_times) -> dict:
    """The output times inside the step just accepted, from the solver's dense
    output, written sample by sample (diffrax's `SaveAt(ts)`)."""
    evaluate = _interpolation(solver, dense)

    def due(state):
        index = state[0]
        t = jnp.take_along_axis(ts, jnp.minimum(index, n_times - 1)[:, None], 1)[:, 0]
        return accepted & (index < n_times) & (t <= c["tnext"]), t

    def save(state):
        index, saved_ys = state
        now, t = due(state)
        y = evaluate(dense, c["tprev"], c["tnext"], t)
        slot_now = jnp.where(now, index, n_times + 1)  # out of range: not written
        saved_ys = jax.tree.map(
            lambda b, v: b.at[rows, slot_now].set(v, mode="drop"), saved_ys, y
        )
        step = now.astype(index.dtype)
        return index + step, saved_ys

    def pending(state):
        return jnp.any(due(state)[0])

    state = (c["next_time"], c["saved_ys"])
    state = jax.lax.while_loop(pending, save, state)
    return dict(zip(("next_time", "saved_ys"), state))
