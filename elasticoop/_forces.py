"""Contact forces $F_c$ on the contact bodies, and wrench -> generalized force."""

import abc
from collections.abc import Callable

import diffrax
import equinox as eqx
import jax.numpy as jnp

from ._custom_types import Scalar, State, Vector3
from ._rotations import get_rotation
from ._validation import as_float_array, require


class AbstractForce(eqx.Module):
    """Generalized forces applied by the manipulators.

    `force(t, y, ydot)` returns shape `(m, 6)` (contact bodies 1..m; the object gets
    $F_0 = 0$) or `(m + 1, 6)` (all bodies, row 0 a disturbance on the object). Each
    row holds three world-axis force components [N] and three generalized torques
    conjugate to the Euler angles [N m] (see `generalized_wrench`).
    """

    @abc.abstractmethod
    def __call__(self, t: Scalar, y: State, ydot: State) -> jnp.ndarray:
        pass

    @property
    def jump_ts(self):
        """Times at which the force has kinks (handed to the step-size controller)."""
        return None


class ConstantForce(AbstractForce):
    """A constant generalized force `F` of shape `(m, 6)` or `(m + 1, 6)`."""

    F: jnp.ndarray

    def __init__(self, F):
        self.F = jnp.asarray(as_float_array(F, "ConstantForce.F", (None, 6)))

    def __call__(self, t, y, ydot):
        return self.F


class SampledForce(AbstractForce):
    """Force samples `F` of shape `(len(ts), m, 6)` (or `(len(ts), m + 1, 6)`) at
    times `ts`, interpolated linearly (`diffrax.LinearInterpolation`). The sample
    times are passed to the step-size controller as jump times so that an adaptive
    solver steps onto the kinks. Simulated times must lie within `ts`."""

    ts: jnp.ndarray
    F: jnp.ndarray

    def __init__(self, ts, F):
        ts = as_float_array(ts, "SampledForce.ts", (None,))
        if ts.shape[0] < 2:
            raise ValueError(
                f"SampledForce.ts needs at least 2 samples, got {ts.shape[0]}"
            )
        ts = require(
            ts, (ts[1:] > ts[:-1]).all(), "SampledForce.ts must be increasing", ts
        )
        self.ts = jnp.asarray(ts)
        self.F = jnp.asarray(
            as_float_array(F, "SampledForce.F", (ts.shape[0], None, 6))
        )

    def __call__(self, t, y, ydot):
        return diffrax.LinearInterpolation(ts=self.ts, ys=self.F).evaluate(t)

    @property
    def jump_ts(self):
        return self.ts


class FeedbackForce(AbstractForce):
    """A force from a callable `fn(t, y, ydot) -> (m, 6)`, e.g. a feedback law."""

    fn: Callable = eqx.field(static=True)

    def __call__(self, t, y, ydot):
        return jnp.asarray(self.fn(t, y, ydot), dtype=jnp.float64)


def as_force(forces) -> AbstractForce | None:
    """Accept `None`, an `AbstractForce`, a callable or a constant array."""
    if forces is None or isinstance(forces, AbstractForce):
        return forces
    if callable(forces):
        return FeedbackForce(forces)
    return ConstantForce(forces)


def generalized_wrench(
    angles: Vector3,
    force: Vector3,
    torque: Vector3,
    frame: str = "world",
    convention: str = "zxz",
) -> jnp.ndarray:
    """Map a physical wrench at a body's mass centre to its generalized force.

    The force enters unchanged (world axes); the torque $\\tau$ maps through the
    virtual-work identity
    $\\tau\\cdot\\omega = Q_{\\mathcal A}\\cdot\\dot{\\mathcal A}$:
    $Q_{\\mathcal A} = L_\\omega^T \\tau$ for a body-frame torque and
    $L_\\omega^T R^T \\tau$ for a world-frame one.

    **Arguments:**

    - `angles`: the body's Euler angles.
    - `force`: force [N], `frame` axes (a body-frame force is rotated to world).
    - `torque`: torque [N m], `frame` axes.
    - `frame`: `"world"` or `"body"`.
    - `convention`: `"zxz"` or `"rpy"`.

    **Returns:** the 6-vector $(F_x, F_y, F_z, Q_{a_1}, Q_{a_2}, Q_{a_3})$.
    """
    if frame not in ("world", "body"):
        raise ValueError(f"frame must be 'world' or 'body', got {frame!r}")
    rotation = get_rotation(convention)
    angles, force, torque = (
        jnp.asarray(as_float_array(v, name, (3,)))
        for v, name in ((angles, "angles"), (force, "force"), (torque, "torque"))
    )
    R = rotation.matrix(angles)
    L = rotation.angular_velocity_matrix(angles)
    if frame == "world":
        torque = R.T @ torque
    else:
        force = R @ force
    return jnp.concatenate([force, L.T @ torque])


def pad_to_bodies(F: jnp.ndarray, n_bodies: int) -> jnp.ndarray:
    """Return `(bodies, 6)` forces from `(m, 6)` contact forces or `(m + 1, 6)`."""
    if F.shape == (n_bodies - 1, 6):
        return jnp.concatenate([jnp.zeros((1, 6), F.dtype), F])
    return F


def check_force_shape(shape, n_bodies: int) -> None:
    m = n_bodies - 1
    if tuple(shape) not in ((m, 6), (n_bodies, 6)):
        raise ValueError(
            f"forces must give shape ({m}, 6) for the m = {m} contact bodies "
            f"(or ({n_bodies}, 6) including the object), got {tuple(shape)}"
        )
