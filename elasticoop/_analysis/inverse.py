"""Inverse dynamics over a whole trajectory."""

import jax
import jax.numpy as jnp

from .._custom_types import ArrayInput, StateSeries
from .._lagrange import inverse_dynamics
from .._models import AbstractElasticModel
from .._validation import as_float_array


@jax.jit
def _over_time(
    model: AbstractElasticModel,
    y: StateSeries,
    ydot: StateSeries,
    yddot: StateSeries,
) -> StateSeries:
    return jax.vmap(inverse_dynamics, in_axes=(None, 0, 0, 0))(model, y, ydot, yddot)


def inverse_dynamics_series(
    model: AbstractElasticModel, y: ArrayInput, ydot: ArrayInput, yddot: ArrayInput
) -> StateSeries:
    """The generalized forces $F = W\\ddot Y + w - G$ that realise a motion, at
    every sample: use it to find the forces behind measured data, or to check them.

    **Arguments:** `y`, `ydot`, `yddot` of shape `(times, bodies, 6)`.

    **Returns:** $F(t)$, `(times, bodies, 6)`: the object's row is what an external
    disturbance on the object would have to be (zero for a consistent motion).
    """
    shape = (None, model.n_bodies, 6)
    y = as_float_array(y, "y", shape)
    ydot = as_float_array(ydot, "ydot", y.shape)
    yddot = as_float_array(yddot, "yddot", y.shape)
    return _over_time(model, *(jnp.asarray(a) for a in (y, ydot, yddot)))
