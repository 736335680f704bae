"""A rigid body and its kinetic energy, written once."""

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Float

from ._custom_types import BodyCoordinate, BodyCoordinates, BodyState, BoolScalar
from ._rotations import AbstractRotation
from ._validation import as_float_array, require, stack, xp

# Relative slack in the triangle inequality A + B >= C (a planar lamina has equality).
_TRIANGLE_RTOL = 1e-12


class RigidBody(eqx.Module):
    """A rigid body: mass $m_i$ and principal moments of inertia $(A_i, B_i, C_i)$
    about its mass centre.

    **Arguments:**

    - `mass`: $m_i > 0$ [kg].
    - `inertia`: $(A_i, B_i, C_i)$ [kg m^2], positive and satisfying the triangle
      inequalities $A + B \\ge C$, $B + C \\ge A$, $C + A \\ge B$.

    Inside a model the bodies are stored stacked: `model.bodies.mass` has shape
    `(bodies,)` and `model.bodies.inertia` shape `(bodies, 3)`.
    """

    mass: Float[Array, "*bodies"]
    inertia: Float[Array, "*bodies 3"]

    def __init__(self, mass, inertia):
        mass = as_float_array(mass, "RigidBody.mass", ())
        inertia = as_float_array(inertia, "RigidBody.inertia", (3,))
        mass = require(mass, mass > 0, "RigidBody.mass must be positive", mass)
        inertia = require(
            inertia, inertia > 0, "RigidBody.inertia must be positive", inertia
        )
        inertia = require(
            inertia,
            _triangle(inertia),
            "RigidBody.inertia violates the triangle inequality "
            "(A + B >= C, B + C >= A, C + A >= B)",
            inertia,
        )
        self.mass = jnp.asarray(mass)
        self.inertia = jnp.asarray(inertia)

    def admissible(self) -> BoolScalar:
        """Whether every body passes the checks of construction (masses and
        principal moments positive, the triangle inequalities): for bodies whose
        values were changed afterwards (`eqx.tree_at`, a Monte Carlo draw).
        Evaluated by NumPy when the values are concrete."""
        np_ = xp(self.mass, self.inertia)
        return (
            np_.all(np_.isfinite(self.mass) & (self.mass > 0))
            & np_.all(np_.isfinite(self.inertia) & (self.inertia > 0))
            & np_.all(_triangle(self.inertia))
        )


def _triangle(inertia):
    """$A + B \\ge C$, $B + C \\ge A$, $C + A \\ge B$ for `inertia` `(..., 3)`,
    within `_TRIANGLE_RTOL` of $A + B + C$."""
    a, b, c = inertia[..., 0], inertia[..., 1], inertia[..., 2]
    slack = _TRIANGLE_RTOL * (a + b + c)
    return (a + b + slack >= c) & (b + c + slack >= a) & (c + a + slack >= b)


def stack_bodies(bodies) -> RigidBody:
    """Stack a sequence of `RigidBody` into one with leading `bodies` axis."""
    if isinstance(bodies, RigidBody):
        if jnp.ndim(bodies.mass) == 0:
            bodies = [bodies]
        else:
            return bodies
    bodies = list(bodies)
    if not bodies:
        raise ValueError("bodies must hold at least one RigidBody (the object)")
    for k, body in enumerate(bodies):
        if not isinstance(body, RigidBody):
            raise ValueError(f"bodies[{k}] must be a RigidBody, got {body!r}")
    return jax.tree.map(lambda *xs: stack(xs), *bodies)


def kinetic_energy(
    body: RigidBody,
    rotation: AbstractRotation,
    y: BodyState | BodyCoordinates,
    ydot: BodyState | BodyCoordinates,
) -> BodyCoordinate:
    """Kinetic energy of one body,
    $T_i = \\tfrac12 m_i |\\dot r_i|^2 + \\tfrac12 \\omega_i^T I_i \\omega_i$,
    $\\omega_i = L_\\omega(\\mathcal{A}_i)\\dot{\\mathcal{A}}_i$.

    This is the only place the kinetic energy is written; the mass matrix
    $W_i = \\partial^2 T_i/\\partial\\dot y_i^2$ and the velocity terms follow by
    autodiff.

    `y` and `ydot` are arrays `(6,)`, or tuples of six arrays (coordinate by
    coordinate) for stacked bodies (`body.mass` `(bodies,)`, `body.inertia`
    `(bodies, 3)`), which gives the `(bodies,)` energies in one elementwise pass.
    """
    v = ydot
    w1, w2, w3 = rotation.angular_velocity_components(y[3:6], ydot[3:6])
    inertia = body.inertia
    translational = v[0] * v[0] + v[1] * v[1] + v[2] * v[2]
    rotational = (
        inertia[..., 0] * w1 * w1
        + inertia[..., 1] * w2 * w2
        + inertia[..., 2] * w3 * w3
    )
    return 0.5 * body.mass * translational + 0.5 * rotational
