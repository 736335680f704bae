"""One step of an explicit Runge-Kutta method on a batch, each sample over its own step.

The batch loop of `batch_loop.py` moves sample $b$ from its time $t_b$ to
$t_b + h_b$ in one step of the solver's Butcher tableau ($a_{ij}$, $b_j$, the error
weights $e_j$, $c_i$), the arithmetic of diffrax's Runge-Kutta step for each sample:

- stage $i$ at $t_b + c_i h_b$ (exactly $t_b + h_b$ where $c_i = 1$), from
  $y_i = y_0 + \\sum_{j<i} a_{ij} k_j$, with $k_j = h_b f_j$ and
  $f_j = f(t_b + c_j h_b, y_j)$;
- $y_1 = y_0 + \\sum_j b_j k_j$ (the last stage's input where the tableau has the
  first-same-as-last property: $b_j = a_{sj}$ for the last stage $s$) and the error
  estimate $\\sum_j e_j k_j$;
- the dense output is diffrax's interpolant of $y_0$, $y_1$ and the $k_j$, linear
  in them with the coefficients of `dense_weights`.

The same step replays the accepted steps in the backward pass of the stepwise
adjoint (`adjoint.py`), a block of steps at a time as a batch, keeping each
stage's input (`stage_inputs=True`) and leaving out the last stage's evaluation,
which neither $y_1$ nor the adjoint needs (`evaluate_last=False`).

What differs is how the sums over stages are written: elementwise, term by term in
the tableau's order, instead of diffrax's dot product of the stage buffer with the
tableau's row. On the CPU the dot products and what they feed cost more than the
stages' arithmetic itself (`benchmarks/loop.py`), and a dot
product with the row of a tableau fuses each product into its sum (FMA), where
XLA's elementwise code rounds the product first. So the results equal diffrax's
step to rounding (about one unit in the last place a stage), not bitwise.

The stages run in a `lax.fori_loop` (one copy of the vector field in the compiled
program: with six copies, one a stage, XLA compiled the vector field slower), over
a buffer of the $k_j$ that the caller keeps from one step to the next. Each stage's
input sums only that stage's terms with a nonzero coefficient, in a branch of a
`lax.switch` on the stage (so a value left in the buffer by an earlier step never
enters). Before, every stage summed all the buffer's rows, masking those not yet
of this step: Dopri8's 13 stages then took 169 terms a step where 91 are
nonzero (`benchmarks/montecarlo.py`).
"""

from collections.abc import Callable
from typing import NamedTuple

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, PyTree, Shaped

from .._compat import dense_interpolation


class BatchStep(NamedTuple):
    """A step of every sample: its end $y_1$, error estimate, the stage increments
    $k_j$ (`(stages, batch, ...)`, also the buffer for the next step), the
    vector field at the last stage (the next step's first where the tableau is
    first-same-as-last) and, where asked, the stages' inputs $y_i$
    (`(stages, batch, ...)`). Without the last stage's evaluation, `y_error` and
    `f_last` are `None`, and so is the last stage's $k$ in `ks` (left as it was)."""

    y1: PyTree[Array]
    y_error: PyTree[Array] | None
    ks: PyTree[Array]
    f_last: PyTree[Array] | None
    inputs: PyTree[Array] | None = None


def stage_time(t0: Array, t1: Array, c_i: float | Array) -> Array:
    """The time $t_0 + c_i h$ of a stage of the step from `t0` to `t1`
    ($h = t_1 - t_0$), exactly `t1` where $c_i = 1$ and `t0` where $c_i = 0$
    (for a finite $h$; as diffrax's stages). `c_i` a number, or a traced scalar
    (the stage of a loop), or an array of them (the times of those stages)."""
    if isinstance(c_i, int | float | np.floating):
        if c_i == 0:
            return t0
        if c_i == 1:
            return t1
        return t0 + c_i * (t1 - t0)
    return jnp.where(c_i == 1, t1, t0 + c_i * (t1 - t0))


def dense_weights(
    solver: diffrax.AbstractSolver,
    t0: Array | float,
    t1: Array | float,
    t: Array | float,
) -> Float[Array, " basis"]:
    """The coefficients $w$ of the solver's dense output at `t` in the step from
    `t0` to `t1` (scalars): diffrax's interpolants of its explicit Runge-Kutta
    solvers are linear in the step's $y_0$, $y_1$ and stage increments $k_i$,
    $y(t) = w_0 y_0 + w_1 y_1 + \\sum_i w_{2+i} k_i$; `(2 + stages,)`, the
    gradient of the interpolant with respect to them."""
    tableau = solver.tableau  # type: ignore[attr-defined]
    stages = tableau.num_stages
    dtype = jnp.result_type(t0, t1, t, float)

    def value(basis):
        dense = dense_interpolation(solver, t0, t1, basis[0], basis[1], basis[2:])
        return dense.evaluate(t)

    return jax.grad(value)(jnp.zeros(stages + 2, dtype))


def stage_buffer(tableau: diffrax.ButcherTableau, y: PyTree[Array]) -> PyTree[Array]:
    """A buffer for the stage increments of a step of the batch `y`."""
    return jax.tree.map(lambda x: jnp.zeros((tableau.num_stages, *x.shape), x.dtype), y)


def by_row(x: Shaped[Array, " batch"], like: Array) -> Array:
    """`x` of shape `(batch,)` shaped to broadcast against `like` row by row."""
    return x.reshape(x.shape + (1,) * (like.ndim - 1))


def _weighted_sum(terms: list[Callable[[Array], Array]], ks: list) -> PyTree[Array]:
    """$\\sum_j$ `terms[j](k_j)`, term by term in the order of $j$."""

    def one(*k):
        total = terms[0](k[0])
        for term, k_j in zip(terms[1:], k[1:], strict=True):
            total = total + term(k_j)
        return total

    return jax.tree.map(one, *ks)


def _weighted(weights: np.ndarray) -> list[Callable[[Array], Array]]:
    def times(w: float) -> Callable[[Array], Array]:
        return lambda k: w * k

    return [times(float(w)) for w in weights]


def _rows(buffer: PyTree[Array], count: int) -> list[PyTree[Array]]:
    return [jax.tree.map(lambda b, j=j: b[j], buffer) for j in range(count)]


def explicit_step(
    tableau: diffrax.ButcherTableau,
    field: Callable[[Float[Array, " batch"], PyTree[Array]], PyTree[Array]],
    t0: Float[Array, " batch"],
    t1: Float[Array, " batch"],
    y0: PyTree[Array],
    f0: PyTree[Array] | None,
    k_buffer: PyTree[Array],
    *,
    stage_inputs: bool = False,
    evaluate_last: bool = True,
) -> BatchStep:
    """Step every sample $b$ of the batch `y0` (leading axis) from `t0[b]` to
    `t1[b]` with the explicit tableau `tableau` (see the module's docstring).
    `field(t, y)`: the vector field of the batch, each sample at its own time. `f0`:
    the vector field at `(t0, y0)` where known (first-same-as-last), else `None`
    (the first stage is evaluated). `k_buffer`: the buffer from `stage_buffer` or
    the last step. `stage_inputs`: also return the stages' inputs.
    `evaluate_last=False`: leave out the last stage's evaluation (its input is
    still formed), for a tableau whose $y_1$ does not use it ($b_s = 0$); no error
    estimate then."""
    if tableau.implicit:
        raise ValueError("explicit_step takes the tableau of an explicit method")
    if not evaluate_last and tableau.b_sol[-1] != 0:
        raise ValueError(
            "explicit_step(evaluate_last=False) takes a tableau whose solution does "
            "not use the last stage"
        )
    n = tableau.num_stages
    dtype = jax.tree.leaves(y0)[0].dtype
    lower = np.zeros((n, n))
    for i, row in enumerate(tableau.a_lower):
        lower[i + 1, : i + 1] = row
    c = jnp.asarray(np.concatenate([[tableau.c1], tableau.c]), dtype)
    h = t1 - t0

    def write(buffer, i, f):
        """The buffer with $k_i = h_b f$ at stage `i`."""
        k = jax.tree.map(lambda v: by_row(h, v) * v, f)
        return jax.tree.map(
            lambda b, v: jax.lax.dynamic_update_index_in_dim(b, v, i, 0), buffer, k
        )

    def input_of(i, ks):
        """$y_0 + \\sum_{j<i} a_{ij} k_j$ over the nonzero $a_{ij}$ only."""
        row = lower[i, :i]
        used = [j for j in range(i) if row[j] != 0]
        if not used:
            return y0
        rows = [jax.tree.map(lambda b, j=j: b[j], ks) for j in used]
        return jax.tree.map(jnp.add, y0, _weighted_sum(_weighted(row[used]), rows))

    def input_at(i, ks):
        return jax.lax.switch(
            i, [lambda ks, i=i: input_of(i, ks) for i in range(n)], ks
        )

    def keep(inputs, i, yi):
        if inputs is None:
            return None
        return jax.tree.map(
            lambda b, v: jax.lax.dynamic_update_index_in_dim(b, v, i, 0), inputs, yi
        )

    def stage(i, carry):
        ks, _, _, inputs = carry
        yi = input_at(i, ks)
        fi = field(stage_time(t0, t1, c[i]), yi)
        # `yi` leaves the loop (the solution where b_j = a_sj): which also keeps
        # XLA from computing the sum again inside each of the vector field's
        # first operations, as it otherwise does
        return write(ks, i, fi), yi, fi, keep(inputs, i, yi)

    inputs = None
    if stage_inputs:
        inputs = keep(stage_buffer(tableau, y0), 0, y0)
    first = 0
    if f0 is not None:
        k_buffer, first = write(k_buffer, 0, f0), 1
    # (the stage's input and vector field start as arrays of their shape, which
    # the first stage overwrites)
    carry = (k_buffer, y0, y0 if f0 is None else f0, inputs)
    carry = jax.lax.fori_loop(first, n if evaluate_last else n - 1, stage, carry)
    k_buffer, y_last, f_last, inputs = carry
    if not evaluate_last:
        y_last = input_of(n - 1, k_buffer)
        inputs = keep(inputs, n - 1, y_last)
    ks = _rows(k_buffer, n)
    if tableau.ssal:  # b_j = a_sj: the last stage's input
        y1 = y_last
    else:
        y1 = jax.tree.map(jnp.add, y0, _nonzero_sum(tableau.b_sol, ks))
    if not evaluate_last:
        return BatchStep(y1, None, k_buffer, None, inputs)
    y_error = _nonzero_sum(tableau.b_error, ks)
    return BatchStep(y1, y_error, k_buffer, f_last, inputs)


def _nonzero_sum(weights: np.ndarray, ks: list) -> PyTree[Array]:
    """$\\sum_j w_j k_j$ over the nonzero $w_j$ (Dopri8's error estimate has 9
    of 14)."""
    used = [j for j, w in enumerate(weights) if w != 0]
    return _weighted_sum(_weighted(np.asarray(weights)[used]), [ks[j] for j in used])
