"""Sums over the entries of a state that XLA's CPU backend compiles to one fused loop.

Under `vmap` (the batch loop of `run_study`), XLA's CPU backend compiles a
reduction over each sample's entries to a library call or to several operations
(a dot product of short vectors: a batched matrix kernel; a float `sum`: a kernel
of XNNPACK; `all` of booleans: a windowed reduction, then a reduction), each with a
fixed cost of a few microseconds a step, more than the arithmetic. Slices and
additions fuse into one loop instead (`benchmarks/loop.py`).
"""

import jax.numpy as jnp
from jaxtyping import Array, Bool, Float


def sum_by_halves(x: Float[Array, " n"]) -> Float[Array, ""]:
    """The sum of a vector, adding its halves until one entry is left (where the
    length is odd, its last entry is set aside and added at the end); 0 if empty."""
    if x.size == 0:
        return jnp.zeros((), x.dtype)
    aside = None
    while x.size > 1:
        if x.size % 2:
            aside = x[-1] if aside is None else aside + x[-1]
            x = x[:-1]
        x = x[: x.size // 2] + x[x.size // 2 :]
    return x[0] if aside is None else x[0] + aside


def all_finite(x: Float[Array, "..."]) -> Bool[Array, ""]:
    """Whether every entry of `x` is finite: $0 \\cdot x_i$ is NaN exactly where
    $x_i$ is not, and the sum of the products is NaN where one of them is."""
    return jnp.isfinite(sum_by_halves(jnp.ravel(x) * 0))
