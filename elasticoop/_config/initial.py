"""A scenario's initial state from its static equilibrium (`[initial] from =
"equilibrium"`), and the forces that hold the contact bodies at rest."""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from .._analysis import Equilibrium, static_equilibrium
from .._compile_options import fast_compile_jit
from .._custom_types import State
from .._forces import AbstractForce, pad_to_bodies
from .._lagrange import elastic_forces
from .._models import AbstractElasticModel

# The values of `[initial] from`.
INITIAL_FROM = ("equilibrium",)


def held_coordinates(
    n_bodies: int, prescribed: Bool[np.ndarray, "bodies 6"] | None
) -> Bool[np.ndarray, "bodies 6"]:
    """The coordinates held while the equilibrium is found: those of the
    `[prescribed]` table, or else every coordinate of the contact bodies (as
    `elasticoop modes` holds them)."""
    if prescribed is not None:
        return np.asarray(prescribed, dtype=bool)
    mask = np.zeros((n_bodies, 6), dtype=bool)
    mask[1:] = True
    return mask


def forces_at_start(
    forces: AbstractForce | None, t0: float, y: State, n_bodies: int
) -> State:
    """The applied generalized forces $F(t_0, Y, 0)$ at rest in `y`, `(bodies, 6)`
    (zero without forces)."""
    if forces is None:
        return jnp.zeros((n_bodies, 6))
    t = jnp.asarray(t0, dtype=jnp.float64)
    return _forces_at_rest(forces, t, jnp.asarray(y), n_bodies)


# Compiled: evaluated op by op, these would compile each small operation on its own
# (seconds in a fresh process).
@fast_compile_jit
def _forces_at_rest(forces: AbstractForce, t: Array, y: State, n_bodies: int) -> State:
    at_rest = forces(t, y, jnp.zeros_like(y))
    return pad_to_bodies(jnp.asarray(at_rest), n_bodies)


def equilibrium_start(
    model: AbstractElasticModel,
    y_guess: Float[np.ndarray, "bodies 6"],
    held: Bool[np.ndarray, "bodies 6"],
    applied: State,
) -> Equilibrium:
    """The static equilibrium $\\partial\\Pi/\\partial Y = G + F$ of the free
    coordinates, with the `held` ones at their values in `y_guess` and the applied
    forces `applied` held constant (`static_equilibrium` with its default
    tolerances). Raises `ValueError` when there is no unique stable one."""
    return static_equilibrium(model, y_guess, held, applied)


def holding_forces(model: AbstractElasticModel, y: State) -> Float[Array, "m 6"]:
    """The generalized forces that hold each contact body at rest in `y`:
    $F_i = \\partial\\Pi/\\partial Y_i - G_i$ for $i = 1..m$, `(m, 6)` (the
    reactions of a static equilibrium with the contact bodies held)."""
    return _holding_forces(model, jnp.asarray(y))


@fast_compile_jit
def _holding_forces(model: AbstractElasticModel, y: State) -> Float[Array, "m 6"]:
    return (elastic_forces(model, y) - model.gravity_forces())[1:]


__all__ = [
    "INITIAL_FROM",
    "equilibrium_start",
    "forces_at_start",
    "held_coordinates",
    "holding_forces",
]
