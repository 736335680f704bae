"""Peak grasp loads of a run: the full elastic + damping load, between the saved
samples too."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from .._custom_types import State
from .._models import AbstractElasticModel, MobileModel
from .._models.mobile import connection_dissipation

# Points per interval between saved samples at which the load is evaluated.
REFINE = 8


def grasp_load(
    model: AbstractElasticModel, y: State, ydot: State
) -> Float[Array, "grasps 6"]:
    """The load each grasp applies, elastic plus damping: per connection on its
    first body, $-\\partial\\Pi_{ij}/\\partial Y_i - \\partial R_{ij}/\\partial\\dot
    Y_i$ (`MobileModel`), or per contact body $k$,
    $-\\partial\\Pi/\\partial Y_k - \\partial R/\\partial\\dot Y_k$
    (`ImmobileModel`)."""
    if isinstance(model, MobileModel):
        pairs = np.asarray(model.pairs)
        if pairs.size == 0:
            return jnp.zeros((0, 6))
        yi, yj = y[pairs[:, 0]], y[pairs[:, 1]]
        vi, vj = ydot[pairs[:, 0]], ydot[pairs[:, 1]]
        damping = jax.vmap(jax.grad(connection_dissipation, argnums=4))(
            model.damping, model.rest_length, yi, yj, vi, vj
        )
        return model.connection_wrench(y) - damping
    elastic, damping = model.restoring_forces(y, ydot)
    return -(elastic + damping)[1:]


@eqx.filter_jit
def _loads(model, y, ydot):
    return jax.vmap(lambda q, v: grasp_load(model, q, v))(y, ydot)


def hermite(
    ts: Float[np.ndarray, " times"],
    y: Float[np.ndarray, "times ..."],
    ydot: Float[np.ndarray, "times ..."],
    refine: int = REFINE,
) -> tuple[Float[np.ndarray, "points ..."], Float[np.ndarray, "points ..."]]:
    """$Y$ and $\\dot Y$ at `refine` evenly spaced points per interval (the saved
    samples included) from the cubic Hermite interpolant through the samples of
    $Y$ and $\\dot Y$ (exact for cubics in time; errors $O(h^4)$ in $Y$ and
    $O(h^3)$ in $\\dot Y$ for a step $h$ between samples)."""
    h = np.diff(ts)[:, None]
    s = np.arange(refine)[None, :] / refine  # (1, refine)
    h00, h10 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s
    h01, h11 = -2 * s**3 + 3 * s**2, s**3 - s**2
    d00, d10 = 6 * s**2 - 6 * s, 3 * s**2 - 4 * s + 1
    d01, d11 = -6 * s**2 + 6 * s, 3 * s**2 - 2 * s
    y0, y1, v0, v1 = y[:-1, None], y[1:, None], ydot[:-1, None], ydot[1:, None]
    hh = h.reshape(*h.shape, *(1,) * (y.ndim - 1))

    def basis(b):
        return b.reshape(*b.shape, *(1,) * (y.ndim - 1))

    y_in = (
        basis(h00) * y0 + basis(h10) * hh * v0 + basis(h01) * y1 + basis(h11) * hh * v1
    )
    v_in = (basis(d00) * y0 + basis(d01) * y1) / hh + basis(d10) * v0 + basis(d11) * v1
    rest = y.shape[1:]
    y_all = np.concatenate([y_in.reshape(-1, *rest), y[-1:]])
    v_all = np.concatenate([v_in.reshape(-1, *rest), ydot[-1:]])
    return y_all, v_all


def peak_grasp_loads(
    traj, refine: int = REFINE
) -> tuple[Float[np.ndarray, " grasps"], Float[np.ndarray, " grasps"]]:
    """Peak |force| [N] and |generalized torque| [N m] per grasp over a run, of the
    full load (`grasp_load`: elastic plus damping), evaluated at the saved samples
    and at `refine - 1` points between each two of them, on the cubic Hermite
    interpolant of the saved $Y$, $\\dot Y$ (see `hermite`). Only the samples up to
    the last finite one count (a run that stopped early)."""
    y, ydot, ts = (np.asarray(a) for a in (traj.y, traj.ydot, traj.ts))
    finite = np.nonzero(np.all(np.isfinite(y) & np.isfinite(ydot), axis=(1, 2)))[0]
    last = int(finite.max(initial=0))
    y, ydot, ts = y[: last + 1], ydot[: last + 1], ts[: last + 1]
    if last > 0 and refine > 1:
        y, ydot = hermite(ts, y, ydot, refine)
    loads = np.asarray(_loads(traj.model, jnp.asarray(y), jnp.asarray(ydot)))
    force = np.linalg.norm(loads[..., :3], axis=-1)
    torque = np.linalg.norm(loads[..., 3:], axis=-1)
    return force.max(axis=0, initial=0.0), torque.max(axis=0, initial=0.0)


__all__ = ["REFINE", "grasp_load", "hermite", "peak_grasp_loads"]
