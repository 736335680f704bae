"""Load distribution: the part of the grasp wrenches that moves the object and the
internal part that only squeezes it.

With $m$ grasps applying wrenches $f_i = (F_i, \\tau_i)$ (world axes, torque about
the grasp point $p_i$), the wrench they exert on the object about its reference
point $p_0$ is $w = Gf$ with the grasp matrix

$$G = [G_1 \\cdots G_m], \\qquad
G_i = \\begin{bmatrix} I & 0 \\\\ [p_i - p_0]_\\times & I \\end{bmatrix}.$$

Every $f$ splits into $f = f_M + f_I$: the motion part
$f_M = G^+ w$, the least-norm set of grasp wrenches that produces the same object
wrench (accelerating it and supporting its weight), and the internal part
$f_I = (I - G^+G) f$ in the null space of $G$, which squeezes or twists the object
without moving it (Walker, Freeman & Marcus, "Analysis of motion and internal loading
of objects grasped by multiple cooperating manipulators", IJRR 10(4), 1991;
Prattichizzo & Trinkle, "Grasping", Springer Handbook of Robotics, 2nd ed., 2016,
ch. 38). Forces and torques have different units, so the norm that defines $G^+$
weights torques by $1/\\ell^2$ with a characteristic length $\\ell$ (default: the
mean distance of the grasps from $p_0$); the split is exact ($Gf_I = 0$,
$f_M + f_I = f$) for every $\\ell$, only the share between the parts depends on it.

The grasp wrenches of a driven run (`grasp_wrenches`) are the reactions of the
prescribed contact bodies, with the contact bodies counted as part of the load.
The appendix's springs are not rotation invariant (docs/model.md, section 3.4):
with unequal $c_x, c_y, c_z$ a link force is not along the link, and Euler-angle
springs between
differently oriented bodies exert unequal physical torques, so $Gf$ then differs
from the rate of the assembly's angular momentum by these internal moments.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._custom_types import ArrayInput, Matrix3, Validated, Vector3, Vector6
from .._trajectory import Trajectory
from .._validation import as_float_array


def _skew(v: Vector3) -> Matrix3:
    x, y, z = v
    return jnp.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def grasp_matrix(
    points: Float[ArrayLike, "m 3"], center: Float[ArrayLike, "3"]
) -> Float[Array, "6 grasp_dofs"]:
    """$G$, shape `(6, 6m)`, for grasp points `(m, 3)` and object point `(3,)`."""
    points = jnp.asarray(points)

    def block(p: Vector3) -> Float[Array, "6 6"]:
        top = jnp.concatenate([jnp.eye(3), jnp.zeros((3, 3))], axis=1)
        bottom = jnp.concatenate([_skew(p - center), jnp.eye(3)], axis=1)
        return jnp.concatenate([top, bottom])

    return jnp.concatenate(list(jax.vmap(block)(points)), axis=1)


class LoadDistribution(eqx.Module):
    """The split $f = f_M + f_I$ of grasp wrenches (see the module docstring).

    **Fields** (leading time axes as in the input):

    - `object_wrench`: $w = Gf$ about the object point, `(..., 6)` [N, N m].
    - `motion`: $f_M$ per grasp, `(..., m, 6)`.
    - `internal`: $f_I$ per grasp, `(..., m, 6)`.
    """

    object_wrench: Float[Array, "*batch 6"]
    motion: Float[Array, "*batch m 6"]
    internal: Float[Array, "*batch m 6"]

    def internal_share(self) -> Float[Array, "*batch"]:
        """$|f_I| / (|f_M| + |f_I|)$ of the grasp forces (force parts only), the
        fraction of the manipulators' effort that only squeezes the object,
        shape `(...)`."""
        fm = jnp.linalg.norm(self.motion[..., :3], axis=-1).sum(-1)
        fi = jnp.linalg.norm(self.internal[..., :3], axis=-1).sum(-1)
        return fi / jnp.maximum(fm + fi, jnp.finfo(fm.dtype).tiny)


def load_distribution(
    wrenches: ArrayInput,
    points: ArrayInput,
    center: ArrayInput,
    length: Validated[float | None] = None,
) -> LoadDistribution:
    """Split grasp wrenches into motion and internal parts.

    **Arguments:**

    - `wrenches`: $(F_i, \\tau_i)$ per grasp, world axes, torque about $p_i$,
      shape `(..., m, 6)`.
    - `points`: grasp points $p_i$, `(..., m, 3)`.
    - `center`: the object's reference point $p_0$, `(..., 3)`.
    - `length`: characteristic length $\\ell$ [m] weighting torques against forces
      (default: mean $|p_i - p_0|$).
    """
    wrenches = jnp.asarray(as_float_array(wrenches, "wrenches", None))
    points = jnp.asarray(as_float_array(points, "points", None))
    center = jnp.asarray(as_float_array(center, "center", None))
    if wrenches.ndim < 2 or wrenches.shape[-1] != 6:
        raise ValueError(f"wrenches must have shape (..., m, 6), got {wrenches.shape}")
    if points.shape != (*wrenches.shape[:-1], 3):
        raise ValueError(
            f"points must have shape {(*wrenches.shape[:-1], 3)}, got {points.shape}"
        )
    if center.shape != (*wrenches.shape[:-2], 3):
        raise ValueError(
            f"center must have shape {(*wrenches.shape[:-2], 3)}, got {center.shape}"
        )
    if length is not None and not (np.isfinite(length) and length > 0):
        raise ValueError(f"length must be a positive number of metres, got {length!r}")
    batch = wrenches.shape[:-2]
    m = wrenches.shape[-2]
    flat = _split_all(
        wrenches.reshape(-1, m, 6),
        points.reshape(-1, m, 3),
        center.reshape(-1, 3),
        length,
    )
    return jax.tree.map(lambda x: x.reshape(*batch, *x.shape[1:]), flat)


def _split(
    wrenches: Float[Array, "m 6"],
    points: Float[Array, "m 3"],
    center: Vector3,
    length: float | None,
) -> LoadDistribution:
    m = wrenches.shape[0]
    ell: Array | float
    if length is None:
        ell = jnp.mean(jnp.linalg.norm(points - center[None, :], axis=-1))
        ell = jnp.where(ell > 0, ell, 1.0)
    else:
        ell = length
    # Weighted least norm: f_M = S G'^+ w with G' = G S, S = diag(1, 1, 1, l, l, l)
    # per grasp, so that |S^-1 f|^2 = |F|^2 + |tau|^2 / l^2 is minimised.
    scale = jnp.tile(jnp.array([1.0, 1.0, 1.0, ell, ell, ell]), m)
    G = grasp_matrix(points, center)
    f = wrenches.reshape(-1)
    w = G @ f
    motion = scale * (jnp.linalg.pinv(G * scale[None, :]) @ w)
    return LoadDistribution(
        object_wrench=w,
        motion=motion.reshape(m, 6),
        internal=(f - motion).reshape(m, 6),
    )


# one program over the batch, not op by op, when called outside `jit`
_split_all = eqx.filter_jit(jax.vmap(_split, in_axes=(0, 0, 0, None)))


def grasp_wrenches(traj: Trajectory) -> Float[Array, "times m 6"]:
    """The wrenches the manipulators exert at the grasps, $(F_i, \\tau_i)$ in world
    axes, shape `(times, m, 6)`: the reactions of the prescribed coordinates of the
    contact bodies (or, where a contact body is not prescribed, nothing) converted
    from generalized forces, $\\tau = R L_\\omega^{-T} Q_{\\mathcal A}$ (the inverse
    of `generalized_wrench`)."""
    if traj.reaction is None:
        raise ValueError(
            "the trajectory has no reactions: simulate with prescribed=... so the "
            "grasp wrenches are the forces that drive the contact bodies"
        )
    rotation = traj.model.rotation

    def physical(angles: Vector3, q: Vector6) -> Vector6:
        R = rotation.matrix(angles)
        L = rotation.angular_velocity_matrix(angles)
        torque = R @ jnp.linalg.solve(L.T, q[3:])
        return jnp.concatenate([q[:3], torque])

    contact_y = traj.y[:, 1:]
    return jax.vmap(jax.vmap(physical))(contact_y[..., 3:], traj.reaction[:, 1:])


def trajectory_load_distribution(
    traj: Trajectory, length: Validated[float | None] = None
) -> LoadDistribution:
    """`load_distribution` of `grasp_wrenches(traj)` about the object's position,
    at every output time."""
    wrenches = grasp_wrenches(traj)
    return load_distribution(wrenches, traj.y[:, 1:, :3], traj.y[:, 0, :3], length)
