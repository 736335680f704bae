"""The step-size controller's error norm has the value (to rounding) and the
derivative of diffrax's default (`optimistix.rms_norm`), checked against it, and
no dot product (what it is for: see `elasticoop/_integrate/error_norm.py`)."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from elasticoop._integrate.error_norm import rms_norm
from elasticoop._integrate.fused_sums import all_finite, sum_by_halves


@pytest.mark.parametrize("size", [1, 2, 3, 7, 38, 782])
def test_value_and_gradient_equal_optimistix(size):
    x = jnp.asarray(np.random.default_rng(size).normal(size=size) * 1e3)
    np.testing.assert_allclose(rms_norm(x), optx.rms_norm(x), rtol=1e-15)
    np.testing.assert_allclose(
        jax.grad(rms_norm)(x), jax.grad(optx.rms_norm)(x), rtol=1e-14, atol=1e-300
    )


def test_batched_compiled_and_pytree():
    xs = jnp.asarray(np.random.default_rng(0).normal(size=(5, 38)))
    np.testing.assert_allclose(
        jax.jit(jax.vmap(rms_norm))(xs), jax.vmap(optx.rms_norm)(xs), rtol=1e-15
    )
    tree = {"a": jnp.arange(6.0).reshape(2, 3), "b": jnp.array([-4.0])}
    np.testing.assert_allclose(rms_norm(tree), optx.rms_norm(tree), rtol=1e-15)
    ours, theirs = jax.grad(rms_norm)(tree), jax.grad(optx.rms_norm)(tree)
    for name in tree:
        np.testing.assert_allclose(ours[name], theirs[name], rtol=1e-15)
    assert float(rms_norm(jnp.zeros(0))) == 0.0
    assert rms_norm(jnp.ones(3, jnp.float32)).dtype == jnp.float32


def test_degenerate_values_and_complex_input():
    zero, inf, nan = jnp.zeros(5), jnp.zeros(5).at[2].set(jnp.inf), jnp.full(5, jnp.nan)
    assert float(rms_norm(zero)) == 0.0
    assert float(rms_norm(inf)) == np.inf
    assert np.isnan(float(rms_norm(nan)))
    # the derivative is optimistix's: 0 at 0 (no NaN); at an infinite entry, reverse
    # mode gives NaN there and forward mode 0
    for x in (zero, inf):
        np.testing.assert_array_equal(jax.grad(rms_norm)(x), jax.grad(optx.rms_norm)(x))
        tangent = jnp.ones(5)
        assert float(jax.jvp(rms_norm, (x,), (tangent,))[1]) == float(
            jax.jvp(optx.rms_norm, (x,), (tangent,))[1]
        )
    np.testing.assert_array_equal(jax.grad(rms_norm)(zero), np.zeros(5))
    with pytest.raises(TypeError, match="real arrays"):
        rms_norm(jnp.ones(3, jnp.complex128))


def test_no_dot_product():
    jaxpr = str(jax.make_jaxpr(jax.vmap(rms_norm))(jnp.ones((4, 38))))
    assert "dot_general" not in jaxpr and "reduce_sum" not in jaxpr
    assert "dot_general" in str(
        jax.make_jaxpr(jax.vmap(optx.rms_norm))(jnp.ones((4, 38)))
    )


@pytest.mark.parametrize("n", [0, 1, 2, 3, 7, 38, 1000])
def test_sum_by_halves_and_all_finite(n):
    x = jnp.asarray(np.random.default_rng(n).normal(size=n))
    np.testing.assert_allclose(sum_by_halves(x), np.sum(np.asarray(x)), atol=1e-12)
    assert bool(all_finite(x))
    if n:
        for bad in (jnp.inf, -jnp.inf, jnp.nan):
            assert not bool(jax.jit(all_finite)(x.at[n // 2].set(bad)))
    # no overflow: 0 * x is 0 for every finite x
    assert bool(all_finite(jnp.full(max(n, 1), 1e308)))
