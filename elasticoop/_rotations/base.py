"""The interface every Euler-angle sequence implements."""

import abc
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from .._compile_options import fast_compile_jit
from .._custom_types import (
    BodyCoordinate,
    BodyCoordinates,
    Matrix3,
    Scalar,
    Vector3,
)

# An entry of $L_\\omega$: an array, or a structural `0.0` or `1.0`.
_Entry = BodyCoordinate | float
_Row = tuple[_Entry, _Entry, _Entry]
AngularVelocityRows = tuple[_Row, _Row, _Row]


class AbstractRotation(eqx.Module):
    """An Euler-angle sequence $\\mathcal{A} = (a_1, a_2, a_3)$.

    Only the rotation matrix $R(\\mathcal{A})$ (body -> world) and the matrix
    $L_\\omega(\\mathcal{A})$ of the body-frame angular velocity
    $\\omega = L_\\omega(\\mathcal{A})\\,\\dot{\\mathcal{A}}$ are written per sequence;
    everything else (mass matrix, velocity terms) follows by differentiation of the
    kinetic energy.
    """

    name: eqx.AbstractClassVar[str]
    angle_names: eqx.AbstractClassVar[tuple[str, str, str]]
    regular_angles: eqx.AbstractClassVar[tuple[float, float, float]]
    singularity_name: eqx.AbstractClassVar[str]

    @abc.abstractmethod
    def matrix(self, angles: Vector3) -> Matrix3:
        """Rotation matrix $R$ taking body-frame vectors to the world frame."""

    @abc.abstractmethod
    def angular_velocity_rows(
        self, angles: Vector3 | BodyCoordinates
    ) -> AngularVelocityRows:
        """The entries of $L_\\omega(\\mathcal{A})$ as three rows of three, with
        structural zeros and ones as Python floats (`0.0`, `1.0`).

        `angles` may be an array `(3,)` or a tuple of three arrays of any common
        shape (the angles of many bodies at once, one array per angle); the entries
        then have that shape. This is the only place $L_\\omega$ is written.
        """

    def angular_velocity_matrix(self, angles: Vector3) -> Matrix3:
        """$L_\\omega(\\mathcal{A})$, with
        $\\omega_{body} = L_\\omega \\dot{\\mathcal{A}}$, shape `(3, 3)`."""
        rows = self.angular_velocity_rows(angles)
        return jnp.stack([jnp.stack(jnp.broadcast_arrays(*row)) for row in rows])

    @abc.abstractmethod
    def regularity(self, angles: Vector3) -> Scalar:
        """A signed measure that vanishes exactly at the sequence's singularity:
        $\\sin\\theta$ for ZXZ, $\\cos(\\text{pitch})$ for RPY ($\\pm\\det L_\\omega$).

        Its sign cannot change without passing through the singularity, which lets
        `simulate` detect a crossing even inside one solver step.
        """

    def gimbal_lock_message(
        self, what: str, detail: str = "below the threshold"
    ) -> str:
        """The one sentence every gimbal-lock error uses: `what` (e.g. "body 1
        starts at") the singularity, `detail` (the measured value)."""
        other = "rpy" if self.name == "zxz" else "zxz"
        return (
            f"{what} the singularity of the {self.name.upper()} Euler angles "
            f"({self.singularity_name} {detail}), where the mass matrix is singular; "
            f"choose other angles or convention={other!r}"
        )

    def check_regular(
        self,
        angles: Float[ArrayLike, "bodies 3"],
        tol: float,
        what: str,
        names: Sequence[str] | None = None,
    ) -> None:
        """Raise `ValueError` if a body of the concrete angles `(bodies, 3)` lies
        within `tol` of the singularity ($|$`regularity`$| <$ `tol`). The message
        names `what` (e.g. `"y_init"`) and the body (its index, or `names[i]`)."""
        reg = np.abs(np.asarray(_regularities(self, jnp.asarray(angles))))
        if np.any(reg < tol):
            i = int(np.argmin(reg))
            body = i if names is None else repr(names[i])
            raise ValueError(
                self.gimbal_lock_message(
                    f"{what}: body {body} starts at gimbal lock,",
                    f"= {reg[i]:.3g} < {tol}",
                )
            )

    def angular_velocity(self, angles: Vector3, angle_rates: Vector3) -> Vector3:
        """Body-frame angular velocity
        $\\omega = L_\\omega(\\mathcal{A})\\dot{\\mathcal{A}}$."""
        return jnp.stack(
            jnp.broadcast_arrays(*self.angular_velocity_components(angles, angle_rates))
        )

    def angular_velocity_components(
        self,
        angles: Vector3 | BodyCoordinates,
        angle_rates: Vector3 | BodyCoordinates,
    ) -> BodyCoordinates:
        """$(\\omega_1, \\omega_2, \\omega_3)$ as a tuple, with `angles` and
        `angle_rates` arrays `(3,)` or tuples of three arrays (many bodies at
        once).

        Written out entry by entry (structural zeros skipped) instead of as a
        matrix-vector product, so that under autodiff and `vmap` the whole kinetic
        energy stays elementwise and XLA fuses it into a few loops.
        """
        rates = (angle_rates[0], angle_rates[1], angle_rates[2])
        out = []
        for row in self.angular_velocity_rows(angles):
            terms = []
            for entry, rate in zip(row, rates):
                if isinstance(entry, float) and entry == 0.0:
                    continue
                terms.append(
                    rate if isinstance(entry, float) and entry == 1.0 else entry * rate
                )
            out.append(sum(terms[1:], terms[0]))
        return tuple(out)


def rot_x(a: Scalar) -> Matrix3:
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.array([[one, zero, zero], [zero, c, -s], [zero, s, c]])


def rot_y(a: Scalar) -> Matrix3:
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.array([[c, zero, s], [zero, one, zero], [-s, zero, c]])


def rot_z(a: Scalar) -> Matrix3:
    c, s = jnp.cos(a), jnp.sin(a)
    one, zero = jnp.ones_like(a), jnp.zeros_like(a)
    return jnp.array([[c, -s, zero], [s, c, zero], [zero, zero, one]])


@fast_compile_jit
def _regularities(rotation: AbstractRotation, angles: Array) -> Array:
    """`regularity` of each body, compiled: `check_regular` runs on every
    `simulate` and scenario, where the operations one by one would each compile."""
    return jax.vmap(rotation.regularity)(angles)
