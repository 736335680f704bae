"""Reverse mode through the accepted steps of an explicit Runge-Kutta solve.

`StepwiseAdjoint` is the discrete adjoint of the solution the solver computed,
written as a rule of `integrate` (`equinox.filter_custom_vjp`) instead of diffrax's
differentiation of its whole loop. The forward run also keeps the start time
$t_n$ and the end time of every accepted step, and the start states $x_n$ of the
first `kept_steps` steps, then of every 2nd, 4th, ... step (`StepLayout`;
`AcceptedSteps`, recorded by the step-size controller, an `AbstractStepRecorder`).
The backward pass goes from the last step to the first and, for step $n$ with
$h$ the step's length (usually $t_{n+1} - t_n$), replays its stages from $x_n$
(itself replayed from the last kept state before it where it was not kept; stage
inputs $X_i = x_n + \\sum_{j<i} a_{ij} K_j$, increments
$K_i = h\\,f(t_n + c_i h, X_i)$, so $x_{n+1} = x_n + \\sum_i b_i K_i$), then applies
the recurrences of the Runge-Kutta adjoint,

$$\\bar K_i = b_i\\,\\bar x_{n+1} + \\bar K_i^{out}
    + \\sum_{l > i} a_{li}\\,\\bar X_l, \\qquad
  (\\bar X_i, \\bar p_i) = h\\,\\bar K_i^T \\frac{\\partial f}{\\partial (X, p)}(X_i),$$
$$\\bar x_n = \\bar x_{n+1} + \\sum_i \\bar X_i + \\bar x_n^{out}, \\qquad
  \\bar p = \\sum_n \\sum_i \\bar p_i,$$

each vector-Jacobian product by autodiff of the vector field at its stage input
(only the stages whose increment has a cotangent). The outputs enter through the
solver's dense output: an output at $\\tau$ in step $n$ is linear in
$(x_n, x_{n+1}, K_1, \\dots, K_s)$, and its cotangent adds to $\\bar x_n^{out}$,
$\\bar x_{n+1}$ and $\\bar K^{out}$ with the interpolation's coefficients at $\\tau$.

Each stage's product is taken in a `jax.lax.cond` of its own, whose operands are
single states or less: the stage's time, input and cotangent, the parameters and
their cotangents so far, and what the vector field reads of the model and the
forces. XLA's CPU runtime (in jax 0.10) runs a nested program (a loop's body, a
branch) one operation after the other in the calling thread where every buffer it
touches holds 512 bytes (64 float64) or less, where it holds at most 8 operations
after fusion, or where its operations form a chain; any other it runs as a graph,
handing its operations to its thread pool and back, which on arrays of a state
costs more than the operations themselves. So the product's branch runs in the
calling thread (up to five bodies, whose state has 62 floats, and forces whose
arrays are as small), and so does the loop over the stages: its body holds 8
operations, with the sum over the later stages an elementwise product and a sum
instead of a dot product and the stages' cotangents updated in one operation
(`benchmarks/defaults.py` times the gradient). Under `vmap`, where a branch on a
batched condition becomes both branches and a choice, a product that every step
needs is taken as it is, and the sum is a dot product, which is quicker there.

The stage inputs are replayed `_BLOCK` steps at a time, in the Runge-Kutta step of
the batch loop (`rk_step.explicit_step`, the block of steps as its batch: one
stage-time rule and one dense-output rule, `stage_time` and `dense_weights`, for
the forward runs and the replay), and the outputs' shares are summed
per step beforehand (a scan over the outputs that starts again at each step's
first), both quicker than replaying step by step or looping over each step's
outputs.

The times of the steps are held fixed, as diffrax's own adjoint holds them (its
step-size controller stops gradients): the two give the same gradients to rounding
(the tests compare them, and with central differences). Each step is replayed
over the times it took: one that ends at a jump time ends there, and the next
starts just after it.
"""

from collections.abc import Callable
from functools import partial
from typing import Any

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array

from .._compat import dense_stages
from .recorder import AcceptedSteps, StepLayout
from .rk_step import by_row, dense_weights, explicit_step, stage_buffer, stage_time

# Steps whose stage inputs the backward pass replays at once (a batch).
_BLOCK = 64


class StepwiseAdjoint(eqx.Module):
    """Reverse-mode gradients of `simulate` through its accepted steps:
    `simulate`'s default for the explicit Runge-Kutta solvers it supports, or
    `adjoint=elasticoop.StepwiseAdjoint(kept_steps=...)` to choose its memory.

    The discrete adjoint of the computed solution, replaying each accepted step
    from its start and taking the products of the vector field at its stages (the
    recurrences are in the docstring of the module `elasticoop._integrate.adjoint`).
    On the default scenario it is the quickest of the reverse modes
    (`benchmarks/gradients.py`).

    - Gradients with respect to the initial state and every floating-point array
      of the model and the forces. Not with respect to the output times `ts`,
      `dt0`, the tolerances or a force's jump times (a `ValueError` says so;
      with the default `adjoint=None` such a gradient is taken by diffrax's
      `RecursiveCheckpointAdjoint` instead). The
      step times are held fixed, as in `diffrax.RecursiveCheckpointAdjoint`: the
      two give the same gradients to rounding.
    - Reverse mode only (`jax.grad`, `jax.vjp`); for forward mode (`jax.jacfwd`)
      use `diffrax.ForwardMode()`.
    - Explicit Runge-Kutta solvers whose dense output is built from the stages
      (Dopri8, the default, Tsit5, Dopri5, Bosh3, Heun, Ralston, Midpoint).
    - Memory: the start and end time of up to `max_steps` steps, and the start
      states of the first `kept_steps` accepted steps, then of every second step
      of the next `2 kept_steps`, every fourth of the next `4 kept_steps`, and so
      on up to `max_steps` (`StepLayout`); the backward pass replays the steps
      between two kept states from the earlier one (once more each, a run of
      more than `kept_steps` steps only). That is $2\\,\\text{max\\_steps} +
      (12(m + 1) + 2)\\,\\text{kept\\_steps}\\,L$ floats, with $L$ the levels it takes
      ($\\text{kept\\_steps}\\,(2^L - 1) \\ge \\text{max\\_steps}$), $L = 6$ at
      the defaults (`max_steps=100_000`, `kept_steps=2048`), allocated and filled
      at each call: a fraction of what keeping every step would take, and
      quicker to fill (`benchmarks/gradients.py`).
    - Under `jax.vmap` (a batch of gradients), the forward half runs in the
      batch loop of `simulate(..., batch_loop=True)`, which writes the record in
      place (`vmap` of diffrax's loop would copy it at every step), and the
      backward pass loops over blocks of steps. Its gradients then are those of
      the batch loop's solution, within the solver's tolerance of each run's
      alone.
    - First derivatives only (as with diffrax's adjoint here).
    """

    kept_steps: int = eqx.field(default=2048, static=True)

    def __check_init__(self) -> None:
        if (
            isinstance(self.kept_steps, bool)
            or not isinstance(self.kept_steps, int | np.integer)
            or self.kept_steps < _BLOCK
        ):
            raise ValueError(
                f"StepwiseAdjoint: kept_steps must be an integer >= {_BLOCK}, got "
                f"{self.kept_steps!r}"
            )

    def layout(self, max_steps: int) -> StepLayout:
        """Where a run of at most `max_steps` steps keeps its steps."""
        return StepLayout.of(max_steps, self.kept_steps)


def check_solver(solver: Any) -> None:
    """A `ValueError` unless `StepwiseAdjoint` supports `solver`: an explicit
    Runge-Kutta solver with a Butcher tableau whose dense output is built from its
    stages (`solver.interpolation_cls(t0, t1, y0, y1, k)`, one `k` per stage)."""
    tableau = getattr(solver, "tableau", None)
    supported = (
        isinstance(solver, diffrax.AbstractERK)
        and isinstance(tableau, diffrax.ButcherTableau)
        and dense_stages(solver) == len(tableau.b_sol)
    )
    if not supported:
        raise ValueError(
            f"StepwiseAdjoint needs an explicit Runge-Kutta solver whose dense output "
            f"is built from its stages (Tsit5, Dopri5, Dopri8, Bosh3, Heun, "
            f"Ralston, Midpoint), got {type(solver).__name__}; use "
            f"adjoint=diffrax.RecursiveCheckpointAdjoint() with this solver"
        )


def stepwise_solve(
    run: Callable[[Any, bool], tuple[Any, AcceptedSteps | None]],
    vector_field: Callable,
    solver: diffrax.AbstractERK,
    layout: StepLayout,
    static: Any,
    arrays: Any,
    run_batch: Callable[[Any, Any], tuple[Any, AcceptedSteps]] | None = None,
    forward: Callable[[Any], Any] | None = None,
    fallback: Callable[[Any, Any], Any] | None = None,
) -> Any:
    """`run(arrays, keep_steps)[0]` (an `Outcome`), differentiated in reverse mode
    as the module's docstring says. `run` returns `(outcome, steps)`: with
    `keep_steps`, the run's `AcceptedSteps` (kept in `layout`), else `None`.
    `arrays` and `static` are `integrate`'s `_Setup` split by `eqx.partition`.
    `run_batch(arrays, batched)`, if given, is what `run(arrays, True)` becomes
    under `jax.vmap` (`batched`: whether each leaf of `arrays` is batched): a batch
    whose record of the steps is not copied at each step, as `vmap` of diffrax's
    loop copies it (the batch loop, `batch_loop.py`). `forward(arrays)`, if given,
    is the solve where nothing is differentiated (default `run(arrays, False)[0]`;
    `integrate` passes one that runs the batch loop under `vmap`).
    `fallback(arrays, outcome_cotangent)`, if given, gives the cotangents of
    `arrays` where a gradient is asked with respect to what this adjoint does not
    differentiate (output times, `dt0`, the controller); without it that is a
    `ValueError`."""
    tableau = solver.tableau
    assert isinstance(tableau, diffrax.ButcherTableau)  # (`check_solver`)
    b = np.asarray(tableau.b_sol, dtype=float)
    a = [np.asarray(row, dtype=float) for row in tableau.a_lower]
    c = np.concatenate([[tableau.c1], np.asarray(tableau.c, dtype=float)])
    stages = len(b)
    # whether stage i's increment enters the step's result or a later stage (else
    # only the dense output, and its product is taken only when an output has it)
    used = [b[i] != 0 or any(a[m - 1][i] != 0 for m in range(i + 1, stages))
            for i in range(stages)]  # fmt: skip
    # the stages the backward pass loops over: all but the trailing ones that only
    # the dense output uses (Dopri5's, Tsit5's and Dopri8's last), which it takes
    # one by one, each in a branch taken where the step has an output (as it takes
    # any such stage inside the loop)
    looped = stages
    while looped > 0 and not used[looped - 1]:
        looped -= 1
    # $\bar K_i$'s weights: $b_i$, and $a_{li}$ of the later stages $l$ (column $i$
    # of the stage matrix, as a row)
    a_matrix = np.zeros((stages, stages))
    for m in range(1, stages):
        a_matrix[m, :m] = a[m - 1][:m]
    b_row = b
    a_columns = a_matrix.T

    def backward(
        nested,
        t_start,
        t_end,
        y_start,
        n,
        where,
        sums,
        x_bar_end,
        diff_args,
        other_args,
    ):
        """The cotangents of the initial state and of `diff_args` from those
        after the last step (`x_bar_end`) and the outputs' shares (`sums`, per
        output, summed per step; `where`: each output's step). `nested`: a loop
        over blocks of steps, each a loop over its steps (what `vmap` gets: in the
        one loop over the steps, its test of whether to replay a block would
        replay one at every step); else one loop over the steps, which is quicker
        for one run (`benchmarks/gradients.py`)."""
        zeros = jax.tree.map(jnp.zeros_like, diff_args)

        def f(t, x, d):
            return vector_field(t, x, eqx.combine(d, other_args, static.args))

        def field_of_batch(t, x):
            return jax.vmap(lambda t, x: f(t, x, diff_args))(t, x)

        def replay_steps(ks, x):
            """Steps `ks` (`(width,)`) replayed from their start states `x`
            (`(width, state)`), in the Runge-Kutta step of the batch loop: the
            stages' inputs $X_i$ (`(width, stages, state)`) and the end states
            $x + \\sum_i b_i K_i$. (The last stage is evaluated only where the
            end state uses it: the backward pass does not need its vector field.)"""
            step = explicit_step(
                tableau,
                field_of_batch,
                t_start[ks],
                t_end[ks],
                x,
                None,
                stage_buffer(tableau, x),
                stage_inputs=True,
                evaluate_last=bool(b[-1] != 0),
            )
            assert step.inputs is not None  # (`stage_inputs=True`)
            return jnp.moveaxis(step.inputs, 0, 1), step.y1

        def step_back(t0, t1, has_output, share, inputs, x_bar, p_bar):
            """The cotangents before a step from those after it, given the step's
            times, the share of its outputs' cotangents and its stage inputs.
            The stages go back in a loop (one vector-Jacobian product in the
            program for all of them, not one per stage: the program compiles in a
            fraction of the time and runs in the same), after the trailing stages
            that only the dense output uses (a product each), taken only when the
            step has an output."""
            h = t1 - t0
            x0_bar, x_bar, k_out = share[0], x_bar + share[1], share[2:]
            b_i, a_i = jnp.asarray(b_row, h.dtype), jnp.asarray(a_columns, h.dtype)
            times = stage_time(t0, t1, jnp.asarray(c, h.dtype))

            def product(t, x, k_bar, d, p_bar):
                return stage_product(f, h, t, x, k_bar, d, p_bar)

            def no_product(t, x, k_bar, d, p_bar):
                return jnp.zeros_like(k_bar), p_bar

            def stage_back(i, stage_bars, p_bar):
                """Stage `i`'s $\\bar X_i$ into `stage_bars` and its $\\bar p_i$
                added to `p_bar`."""
                # (one run: an elementwise product and a sum, a dot product under
                # `vmap`; the module's docstring says why)
                if nested:
                    later = jnp.tensordot(a_i[i], stage_bars, 1)
                else:
                    later = jnp.sum(by_row(a_i[i], stage_bars) * stage_bars, axis=0)
                k_bar = b_i[i] * x_bar + k_out[i] + later
                if isinstance(i, int):
                    needed = None if used[i] else has_output
                elif all(used[:looped]):
                    needed = None
                else:
                    needed = jnp.asarray(used)[i] | has_output
                # The product in a branch of its own, on the stage's own small
                # arrays (see the module's docstring); every accepted step has
                # h > 0, and one of length zero would have no product (its
                # increments are $h f = 0$). (Under `vmap`, where a branch on a
                # batched condition becomes both branches and a choice, a product
                # that is always needed is taken as it is.)
                operands = (times[i], inputs[i], k_bar, diff_args, p_bar)
                if nested and needed is None:
                    stage_bar, p_bar = product(*operands)
                else:
                    taken = h != 0 if needed is None else needed & (h != 0)
                    stage_bar, p_bar = jax.lax.cond(
                        taken, product, no_product, *operands
                    )
                stage_bars = jax.lax.dynamic_update_index_in_dim(
                    stage_bars, stage_bar, i, 0
                )
                return stage_bars, p_bar

            stage_bars = jnp.zeros_like(inputs)
            for i in reversed(range(looped, stages)):
                stage_bars, p_bar = stage_back(i, stage_bars, p_bar)
            stage_bars, p_bar = jax.lax.fori_loop(
                0,
                looped,
                lambda j, carry: stage_back(looped - 1 - j, *carry),
                (stage_bars, p_bar),
            )
            x_bar = x_bar + jnp.sum(stage_bars, axis=0) + x0_bar
            return x_bar, p_bar

        def replay(top):
            """The stage inputs of steps `top - _BLOCK + 1 ... top` (clipped at 0),
            replayed at once (a batch) from their start states: kept ones, or
            past the first `layout.kept` steps computed one after the other from
            the last kept state before them."""
            ks = jnp.maximum(top - _BLOCK + 1 + jnp.arange(_BLOCK, dtype=jnp.int32), 0)
            starts = y_start[jnp.minimum(ks, layout.kept - 1)]
            if layout.levels > 1:
                first = ks[0]
                start, slot = layout.checkpoint(first)

                def advance(k, carry):
                    x, starts = carry
                    # (steps before `first` write row 0, which `first` overwrites)
                    row = jnp.maximum(k - first, 0)
                    starts = jax.lax.dynamic_update_index_in_dim(starts, x, row, 0)
                    return replay_steps(k[None], x[None])[1][0], starts

                # (no step to advance while the block is among the kept steps)
                stop = jnp.where(top < layout.kept, start, top + 1)
                _, chained = jax.lax.fori_loop(
                    start, stop, advance, (y_start[slot], starts)
                )
                starts = jnp.where((ks < layout.kept)[:, None], starts, chained)
            return replay_steps(ks, starts)[0]

        def back_through(k, inputs, x_bar, p_bar):
            """The cotangents before step `k` from those after it (unchanged if
            `k < 0`), given its stage inputs."""
            # the outputs in this step: `lo <= j < hi` (in time order)
            lo = jnp.sum(where < k, dtype=jnp.int32)
            hi = jnp.sum(where <= k, dtype=jnp.int32)
            has_output = hi > lo
            share = jnp.where(has_output, sums[jnp.maximum(hi - 1, 0)], 0.0)
            # the step's own work in a branch, taken for k >= 0. (k < 0 in the
            # last block of the loop over blocks, where the branch is not taken,
            # or under `vmap` its results discarded: `t_start[k]` wraps around.
            # Clipped, `max(k, 0)`, it made the backward pass slower.)
            return jax.lax.cond(
                k >= 0,
                step_back,
                lambda t0, t1, has_output, share, inputs, x_bar, p_bar: (x_bar, p_bar),
                t_start[k],
                t_end[k],
                has_output,
                share,
                inputs,
                x_bar,
                p_bar,
            )

        def body(carry):
            """One step back, replaying a block when the step leaves the last."""
            k, x_bar, p_bar, block, top = carry
            stale = k < top - _BLOCK + 1
            top = jnp.where(stale, k, top)
            block = jax.lax.cond(stale, replay, lambda top: block, top)
            inputs = block[k - (top - _BLOCK + 1)]
            x_bar, p_bar = back_through(k, inputs, x_bar, p_bar)
            return k - 1, x_bar, p_bar, block, top

        def block_back(carry):
            """The `_BLOCK` steps back that end with step `top`."""

            def step_of_block(j, carry):
                top, block, x_bar, p_bar = carry
                inputs = block[_BLOCK - 1 - j]
                x_bar, p_bar = back_through(top - j, inputs, x_bar, p_bar)
                return top, block, x_bar, p_bar

            top, x_bar, p_bar = carry
            _, _, x_bar, p_bar = jax.lax.fori_loop(
                0, _BLOCK, step_of_block, (top, replay(top), x_bar, p_bar)
            )
            return top - _BLOCK, x_bar, p_bar

        if nested:
            # a loop over blocks, each a loop over its steps
            _, x_bar, p_bar = jax.lax.while_loop(
                lambda carry: carry[0] >= 0, block_back, (n - 1, x_bar_end, zeros)
            )
        else:
            # one loop over the steps, replaying a block when it leaves the last
            # (the first step back replays the first block: the loop starts with
            # one that ends past the last step, so that the program holds one
            # replay)
            no_block = jnp.zeros(jax.eval_shape(replay, n - 1).shape, y_start.dtype)
            _, x_bar, p_bar, _, _ = jax.lax.while_loop(
                lambda carry: carry[0] >= 0,
                body,
                (n - 1, x_bar_end, zeros, no_block, n - 1 + _BLOCK),
            )
        return x_bar, p_bar

    @eqx.filter_custom_vjp
    def solve(arrays):
        if forward is not None:
            return forward(arrays)
        return run(arrays, False)[0]

    def record(arrays):
        return run(arrays, True)

    if run_batch is not None:
        record = jax.custom_batching.custom_vmap(record)

        @record.def_vmap
        def _record_batch(axis_size, in_batched, arrays):
            (batched,) = in_batched
            out = run_batch(arrays, batched)
            return out, jax.tree.map(lambda _: True, out)

    @solve.def_fwd
    def solve_fwd(perturbed, arrays):
        outcome, steps = record(arrays)
        return outcome, (outcome.ts, steps)

    @solve.def_bwd
    def solve_bwd(residuals, grad_outcome, perturbed, arrays):
        if fallback is not None and _beyond_adjoint(perturbed):
            return fallback(arrays, grad_outcome)
        _check_perturbed(perturbed)
        out_ts, steps = residuals
        t_start, t_end, y_start = steps.t_start, steps.t_end, steps.y_start
        # products with respect to the perturbed arrays of `args` only
        diff_args, other_args = eqx.partition(arrays.args, perturbed.args)

        ys_bar = grad_outcome.ys
        if ys_bar is None:
            ys_bar = jnp.zeros((out_ts.shape[0], *y_start.shape[1:]), y_start.dtype)
        n = steps.n_accepted  # accepted steps
        last = jnp.maximum(n - 1, 0)
        # (padding past the last step: no output searches into it)
        rows = jnp.arange(t_start.shape[0], dtype=jnp.int32)
        t_start = jnp.where(rows < n, t_start, jnp.inf)

        # The saves: the outputs the run reached, then its end state (diffrax fills
        # the slots in order; the rest, inf, have no cotangent). The outputs'
        # steps and interpolation weights:
        end = jnp.maximum(jnp.sum(jnp.isfinite(out_ts), dtype=jnp.int32) - 1, 0)
        reached = jnp.arange(out_ts.shape[0], dtype=jnp.int32) < end
        tau = jnp.where(reached, out_ts, t_start[0])
        tau_bar = jnp.where(reached[:, None], ys_bar, 0.0)
        where = jnp.searchsorted(t_start, tau, side="left").astype(jnp.int32)
        where = jnp.clip(where - 1, 0, last)
        # (the end state and the slots after it come last: in the last step, with
        # no weight)
        where = jnp.where(reached, where, last)
        weights = jax.vmap(lambda t0, t1, t: dense_weights(solver, t0, t1, t))(
            t_start[where], t_end[where], tau
        )
        weights = jnp.where(reached[:, None] & (n > 0), weights, 0.0)

        # each output's share of the cotangents of (x_n, x_{n+1}, K_1 ... K_s) of
        # its step, summed over each step's outputs (a range of them: a sum that
        # starts again at each step's first output)
        shares = weights[:, :, None] * tau_bar[:, None, :]
        first = jnp.concatenate([jnp.array([True]), where[1:] != where[:-1]])

        def add(left, right):
            (first_left, sum_left), (first_right, sum_right) = left, right
            restart = first_right[:, None, None]
            return first_left | first_right, jnp.where(
                restart, sum_right, sum_left + sum_right
            )

        _, sums = jax.lax.associative_scan(add, (first, shares))
        x_bar, p_bar = _vmap_as(partial(backward, False), partial(backward, True))(
            t_start, t_end, y_start, n, where, sums, ys_bar[end], diff_args, other_args
        )
        # a run without a step: its outputs are x_0 itself
        x_bar = x_bar + jnp.where(n == 0, jnp.sum(tau_bar, axis=0), 0.0)

        none = jax.tree.map(lambda _: None, arrays)
        return eqx.tree_at(
            lambda s: (s.y0, s.args), none, (x_bar, p_bar), is_leaf=_is_none
        )

    return solve(arrays)


def stage_product(
    field: Callable, h: Array, t: Array, x: Array, k_bar: Array, d: Any, p_bar: Any
) -> tuple[Array, Any]:
    """One stage's vector-Jacobian product: $(\\bar X_i, \\bar p + \\bar p_i)$
    with $(\\bar X_i, \\bar p_i) = h\\,\\bar K_i^T \\partial f/\\partial (X, p)$
    at the stage's time `t` and input `x` (`k_bar`: $\\bar K_i$), by autodiff of
    `field(t, x, d)` in `x` and the differentiated arrays `d`; `p_bar`: the
    cotangents of `d` so far."""
    _, pullback = jax.vjp(lambda y, d: field(t, y, d), x, d)
    stage_bar, d_bar = pullback(h * k_bar)
    return stage_bar, jax.tree.map(jnp.add, p_bar, d_bar)


def _vmap_as(fn: Callable, batched_fn: Callable) -> Callable:
    """`fn`, which under `jax.vmap` runs `jax.vmap(batched_fn)` instead (through
    `jax.custom_batching.custom_vmap`, which tells the batch apart also inside a
    function compiled before `vmap` reached it)."""
    wrapped = jax.custom_batching.custom_vmap(fn)

    @wrapped.def_vmap
    def _batched(axis_size, in_batched, *args):
        in_axes = tuple(jax.tree.map(lambda b: 0 if b else None, in_batched))
        out = jax.vmap(batched_fn, in_axes=in_axes, axis_size=axis_size)(*args)
        return out, jax.tree.map(lambda _: True, out)

    return wrapped


def _is_none(value: Any) -> bool:
    return value is None


_NOT_DIFFERENTIATED = {
    "ts": "output times ts",
    "dt0": "first step dt0",
    "controller": "step-size controller (its tolerances, or a SampledForce's "
    "jump times: differentiate with respect to its values F only)",
}


def _beyond_adjoint(perturbed: Any) -> bool:
    """Whether a gradient is asked with respect to what the adjoint does not
    differentiate."""
    return any(
        any(jax.tree.leaves(getattr(perturbed, name))) for name in _NOT_DIFFERENTIATED
    )


def _check_perturbed(perturbed: Any) -> None:
    """A `ValueError` if a gradient is asked with respect to what the adjoint does
    not differentiate (output times, `dt0`, the controller's tolerances and jump
    times)."""
    for name, description in _NOT_DIFFERENTIATED.items():
        if any(jax.tree.leaves(getattr(perturbed, name))):
            raise ValueError(
                f"StepwiseAdjoint differentiates with respect to the initial state "
                f"and the model's and forces' parameters only, not the solve's "
                f"{description}; use adjoint=diffrax.RecursiveCheckpointAdjoint() "
                f"for that"
            )


def default_adjoint(
    solver: diffrax.AbstractSolver,
) -> tuple[StepwiseAdjoint | diffrax.AbstractAdjoint, bool]:
    """The adjoint a solve with `solver` gets by default, and whether gradients it
    does not take fall back on diffrax's: `StepwiseAdjoint()` for the explicit
    Runge-Kutta solvers it supports (with the fallback), else
    `diffrax.RecursiveCheckpointAdjoint()`."""
    try:
        check_solver(solver)
    except ValueError:
        return diffrax.RecursiveCheckpointAdjoint(), False
    return StepwiseAdjoint(), True
