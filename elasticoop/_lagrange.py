"""Lagrange's equations with dissipation, by autodiff of $T$, $\\Pi$ and $R$.

$$W(Y)\\ddot Y + w(Y, \\dot Y) = G + F, \\qquad W = \\partial^2 T/\\partial \\dot Y^2,$$
$$w = \\frac{\\partial^2 T}{\\partial \\dot Y\\,\\partial Y}\\dot Y
      - \\frac{\\partial T}{\\partial Y}
      + \\frac{\\partial R}{\\partial \\dot Y} + \\frac{\\partial \\Pi}{\\partial Y}.$$

$W$ is block diagonal: it is built and solved per body (6x6 blocks, vmapped), and the
velocity terms come from one Jacobian-vector product per body. Nothing here is
derived by hand.
"""

import jax
import jax.numpy as jnp

from ._body import RigidBody, kinetic_energy
from ._custom_types import BodyState, State
from ._models import AbstractElasticModel
from ._rotations import AbstractRotation


def _body_terms(body: RigidBody, rotation: AbstractRotation, y: BodyState, ydot):
    """$W_i$ and the velocity terms
    $(\\partial^2 T_i/\\partial\\dot y_i \\partial y_i)\\dot y_i
    - \\partial T_i/\\partial y_i$
    of one body."""

    def energy(q, v):
        return kinetic_energy(body, rotation, q, v)

    momentum = jax.grad(energy, argnums=1)
    W = jax.jacfwd(momentum, argnums=1)(y, ydot)
    _, momentum_rate = jax.jvp(lambda q: momentum(q, ydot), (y,), (ydot,))
    return W, momentum_rate - jax.grad(energy, argnums=0)(y, ydot)


_per_body = jax.vmap(_body_terms, in_axes=(0, None, 0, 0))


def mass_matrix(model: AbstractElasticModel, y: State) -> jax.Array:
    """The diagonal blocks $W_i(Y_i)$ of the mass matrix, shape `(bodies, 6, 6)`."""
    W, _ = _per_body(model.bodies, model.rotation, y, jnp.zeros_like(y))
    return W


def velocity_terms(model: AbstractElasticModel, y: State, ydot: State) -> State:
    """$\\dot W_i \\dot Y_i - \\partial T_i/\\partial Y_i$ per body, shape
    `(bodies, 6)` (the Coriolis and centrifugal terms of $w$)."""
    _, c = _per_body(model.bodies, model.rotation, y, ydot)
    return c


def elastic_forces(model: AbstractElasticModel, y: State) -> State:
    """$\\partial \\Pi/\\partial Y$, shape `(bodies, 6)` (includes the
    $\\partial\\pi_a/\\partial Y$ term of Appendix B)."""
    return jax.grad(model.potential)(y)


def damping_forces(model: AbstractElasticModel, y: State, ydot: State) -> State:
    """$\\partial R/\\partial \\dot Y$, shape `(bodies, 6)`."""
    return jax.grad(model.dissipation, argnums=1)(y, ydot)


def accelerations(model: AbstractElasticModel, y: State, ydot: State, applied: State):
    """Solve $W\\ddot Y = G + F - w$ per body.

    **Arguments:** the model, $Y$, $\\dot Y$ and the applied generalized forces $F$
    (all `(bodies, 6)`).

    **Returns:** `(yddot, damping)`, the accelerations and
    $\\partial R/\\partial\\dot Y$
    (whose product with $\\dot Y$ is the dissipated power $2R$).
    """
    W, c = _per_body(model.bodies, model.rotation, y, ydot)
    damping = damping_forces(model, y, ydot)
    rhs = model.gravity_forces() + applied - c - damping - elastic_forces(model, y)
    yddot = jax.vmap(jnp.linalg.solve)(W, rhs)
    return yddot, damping


def inverse_dynamics(
    model: AbstractElasticModel, y: State, ydot: State, yddot: State
) -> State:
    """Generalized forces that realise a motion: $F = W\\ddot Y + w - G$,
    shape `(bodies, 6)`."""
    W, c = _per_body(model.bodies, model.rotation, y, ydot)
    inertial = jnp.einsum("bij,bj->bi", W, yddot)
    return (
        inertial
        + c
        + damping_forces(model, y, ydot)
        + elastic_forces(model, y)
        - model.gravity_forces()
    )
