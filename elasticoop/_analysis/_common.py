"""Helpers shared by the analysis functions: masks and constant forces."""

import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool

from .._custom_types import ArrayInput, State
from .._forces import check_force_shape, pad_to_bodies
from .._validation import as_float_array


def as_mask(
    mask: ArrayInput | None, n_bodies: int, name: str = "prescribed"
) -> Bool[np.ndarray, "bodies 6"]:
    """A bool `(bodies, 6)` array of prescribed coordinates (`None`: none)."""
    if mask is None:
        return np.zeros((n_bodies, 6), dtype=bool)
    arr = np.asarray(mask)
    if arr.dtype != np.bool_ or arr.shape != (n_bodies, 6):
        raise ValueError(
            f"{name} must be a bool array of shape ({n_bodies}, 6), got dtype "
            f"{arr.dtype} and shape {arr.shape}"
        )
    return arr


def constant_forces(forces: ArrayInput | None, n_bodies: int) -> State:
    """Constant generalized forces as `(bodies, 6)` (`None`: zero)."""
    if forces is None:
        return jnp.zeros((n_bodies, 6))
    arr = as_float_array(forces, "forces", (None, 6))
    check_force_shape(arr.shape, n_bodies)
    return pad_to_bodies(jnp.asarray(arr), n_bodies)
