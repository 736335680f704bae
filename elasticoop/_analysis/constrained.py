"""Lagrange's equations with some coordinates prescribed."""

import jax
import jax.numpy as jnp

from .._custom_types import State
from .._lagrange import damping_forces, elastic_forces, mass_matrix, velocity_terms
from .._models import AbstractElasticModel


def constrained_accelerations(
    model: AbstractElasticModel,
    y: State,
    ydot: State,
    applied: State,
    mask,
    yddot_prescribed: State,
):
    """Accelerations and reactions with the coordinates in `mask` prescribed.

    With $f$ the free and $p$ the prescribed coordinates of each body, the free rows
    of $W\\ddot Y + w = G + F$ are solved for $\\ddot Y_f$ given $\\ddot Y_p$,

    $$W_{ff}\\ddot Y_f = (G + F - w)_f - W_{fp}\\ddot Y_p,$$

    and the prescribed rows give the reactions, the generalized forces the drive
    must add to realise the motion: $Q_p = [W\\ddot Y + w - G - F]_p$ ($Q_f = 0$).
    Solved per body as one $6\\times 6$ system whose prescribed rows are replaced by
    unit rows.

    **Returns:** `(yddot, damping, reaction)`, each `(bodies, 6)`, where `damping`
    is $\\partial R/\\partial\\dot Y$.
    """
    mask = jnp.asarray(mask, dtype=bool)
    W = mass_matrix(model, y)
    damping = damping_forces(model, y, ydot)
    rhs = (
        model.gravity_forces()
        + applied
        - velocity_terms(model, y, ydot)
        - damping
        - elastic_forces(model, y)
    )
    system = jnp.where(mask[:, :, None], jnp.eye(6), W)
    yddot = jax.vmap(jnp.linalg.solve)(system, jnp.where(mask, yddot_prescribed, rhs))
    reaction = jnp.where(mask, jnp.einsum("bij,bj->bi", W, yddot) - rhs, 0.0)
    return yddot, damping, reaction
