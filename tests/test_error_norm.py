"""The step-size controller's error norm has the value and the derivative of
diffrax's default (`optimistix.rms_norm`), checked against it."""

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

from elasticoop._error_norm import rms_norm


@pytest.mark.parametrize("size", [1, 2, 3, 7, 38, 782])
def test_value_and_gradient_equal_optimistix(size):
    x = jnp.asarray(np.random.default_rng(size).normal(size=size) * 1e3)
    np.testing.assert_allclose(rms_norm(x), optx.rms_norm(x), rtol=1e-15)
    np.testing.assert_allclose(
        jax.grad(rms_norm)(x), jax.grad(optx.rms_norm)(x), rtol=1e-14, atol=1e-300
    )


def test_pytree_and_empty():
    tree = {"a": jnp.arange(6.0).reshape(2, 3), "b": jnp.array([-4.0])}
    np.testing.assert_allclose(rms_norm(tree), optx.rms_norm(tree), rtol=1e-15)
    assert float(rms_norm(jnp.zeros(0))) == 0.0


def test_degenerate_values():
    zero, inf, nan = jnp.zeros(5), jnp.zeros(5).at[2].set(jnp.inf), jnp.full(5, jnp.nan)
    assert float(rms_norm(zero)) == 0.0
    assert float(rms_norm(inf)) == np.inf
    assert np.isnan(float(rms_norm(nan)))
    # the derivative is optimistix's: 0 at 0 (no NaN), NaN at an infinite entry
    for x in (zero, inf):
        np.testing.assert_array_equal(jax.grad(rms_norm)(x), jax.grad(optx.rms_norm)(x))
    np.testing.assert_array_equal(jax.grad(rms_norm)(zero), np.zeros(5))
