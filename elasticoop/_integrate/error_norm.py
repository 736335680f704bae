"""The error norm of `simulate`'s step-size controller.

`rms_norm` has the value (to rounding: the sum's order differs) and the derivative
of diffrax's default error norm (`optimistix.rms_norm`, the root mean square of the
entries), with the sum of the squares written as additions of halves instead of a
dot product (`fused_sums.py`). Under `vmap` (the batch loop) XLA's CPU backend
compiles that dot product of short vectors, batched, to a library kernel with a
large fixed cost, comparable to a stage of the vector field
(`benchmarks/montecarlo.py`, `benchmarks/loop.py`).
"""

import math

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, PyTree

from .._custom_types import Scalar
from .fused_sums import sum_by_halves


def rms_norm(x: PyTree[Array]) -> Scalar:
    """$\\sqrt{\\sum_i x_i^2 / n}$ over the $n$ real entries of the arrays of `x`
    (0 for none); its derivative is optimistix's (0 where the norm is 0)."""
    leaves = jax.tree.leaves(x)
    if any(jnp.iscomplexobj(leaf) for leaf in leaves):
        raise TypeError("rms_norm takes real arrays (the state simulate integrates)")
    size = sum(np.size(leaf) for leaf in leaves)
    if size == 0:
        dtype = jnp.result_type(*leaves) if leaves else jnp.result_type(float)
        return jnp.zeros((), dtype)
    flat = jnp.concatenate([jnp.ravel(leaf) for leaf in leaves])
    return _root_sum_squares(flat) / math.sqrt(size)


@jax.custom_jvp
def _root_sum_squares(x: Array) -> Scalar:
    return jnp.sqrt(sum_by_halves(x * x))


@_root_sum_squares.defjvp
def _root_sum_squares_jvp(
    primals: tuple[Array], tangents: tuple[Array]
) -> tuple[Array, Array]:
    (x,), (tx,) = primals, tangents
    out = _root_sum_squares(x)
    degenerate = (out == 0) | jnp.isinf(out)
    scale = jnp.where(degenerate, 1.0, out)
    return out, jnp.where(degenerate, 0.0, sum_by_halves(x / scale * tx))
