"""Helpers shared by the analysis functions: masks, free coordinates, forces."""

import jax.numpy as jnp
import numpy as np

from .._forces import check_force_shape, pad_to_bodies
from .._validation import as_float_array


def as_mask(mask, n_bodies: int, name: str = "prescribed") -> np.ndarray:
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


def constant_forces(forces, n_bodies: int):
    """Constant generalized forces as `(bodies, 6)` (`None`: zero)."""
    if forces is None:
        return jnp.zeros((n_bodies, 6))
    arr = as_float_array(forces, "forces", (None, 6))
    check_force_shape(arr.shape, n_bodies)
    return pad_to_bodies(jnp.asarray(arr), n_bodies)


def coordinate_names(n_bodies: int, convention: str, body_names=None) -> list[str]:
    """Names `{body}.{coordinate}` of the stacked $Y$, in order (bodies named
    `body0`, `body1`, ... unless `body_names` are given)."""
    angles = (
        ("psi", "theta", "phi") if convention == "zxz" else ("roll", "pitch", "yaw")
    )
    coords = ("x", "y", "z", *angles)
    if body_names is None:
        body_names = [f"body{i}" for i in range(n_bodies)]
    if len(body_names) != n_bodies:
        raise ValueError(
            f"body_names must name the {n_bodies} bodies, got {list(body_names)}"
        )
    return [f"{name}.{c}" for name in body_names for c in coords]
