"""Linearize Appendix B about an unloaded configuration into Appendix A."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._custom_types import ArrayInput, State, Validated
from .._validation import as_float_array, is_concrete
from .immobile import ImmobileModel
from .mobile import MobileModel

# |dPi/dY| at an unloaded state, relative to (largest stiffness) x (length scale).
UNLOADED_RTOL = 1e-8


def linearize_mobile(model: Validated[MobileModel], y0: ArrayInput) -> ImmobileModel:
    """The Appendix A model that agrees with `model` to first order about `y0`.

    $K = \\partial^2 \\Pi/\\partial Y^2 (Y_0)$ and
    $D = \\partial^2 R/\\partial \\dot Y^2 (Y_0, 0)$, both by autodiff; bodies, gravity
    and convention are kept. Small motions of the two models differ by
    $O(\\varepsilon^2)$ in the amplitude $\\varepsilon$. At the rest length each link
    is stiff only along its own direction, so rank K is $4m$ for $m$ links in a tree.

    **Arguments:**

    - `model`: a `MobileModel`.
    - `y0`: an unloaded configuration of it, shape `(bodies, 6)` (see
      `MobileModel.with_unloaded_state` to make one unloaded).

    **Returns:** an `ImmobileModel`.
    """
    if not isinstance(model, MobileModel):
        raise ValueError(f"model must be a MobileModel, got {type(model).__name__}")
    y0 = jnp.asarray(as_float_array(y0, "y0", (model.n_bodies, 6)))
    grad, K, D = _derivatives(model, y0)
    if is_concrete(grad):
        scale = float(jnp.max(model.stiffness, initial=1.0)) * max(
            1.0, float(jnp.max(model.rest_length, initial=1.0))
        )
        worst = float(np.max(np.abs(np.asarray(grad)), initial=0.0))
        if worst > UNLOADED_RTOL * scale:
            raise ValueError(
                f"y0 is not an unloaded configuration of the model: the elastic "
                f"force there reaches {worst:.3e}; use "
                f"model.with_unloaded_state(y0) to make it the unloaded state"
            )
    return ImmobileModel(
        model.bodies,
        0.5 * (K + K.T),
        0.5 * (D + D.T),
        y0,
        gravity=model.gravity,
        convention=model.convention,
    )


@eqx.filter_jit  # one program, not op by op, when called outside `jit`
def _derivatives(
    model: MobileModel, y0: State
) -> tuple[State, Float[Array, "n n"], Float[Array, "n n"]]:
    """$\\partial\\Pi/\\partial Y$, $\\partial^2\\Pi/\\partial Y^2$ and
    $\\partial^2 R/\\partial\\dot Y^2$ at $(Y_0, 0)$, the last two flattened
    `(6 bodies, 6 bodies)`."""
    D = jax.hessian(lambda v: model.dissipation(y0, v.reshape(y0.shape)))(
        jnp.zeros(y0.size)
    )
    return jax.grad(model.potential)(y0), model.stiffness_matrix(y0), D
