"""The appendix's ZXZ Euler angles $(\\psi, \\theta, \\varphi)$."""

import jax.numpy as jnp

from .._custom_types import BodyCoordinates, Matrix3, Scalar, Vector3
from .._naming import ANGLE_NAMES
from .base import AbstractRotation, AngularVelocityRows, rot_x, rot_z


class ZXZ(AbstractRotation):
    """ZXZ Euler angles, $R = R_z(\\psi) R_x(\\theta) R_z(\\varphi)$.

    $$L_\\omega = \\begin{bmatrix}
        \\sin\\theta\\sin\\varphi & \\cos\\varphi & 0 \\\\
        \\sin\\theta\\cos\\varphi & -\\sin\\varphi & 0 \\\\
        \\cos\\theta & 0 & 1 \\end{bmatrix}$$

    Singular (gimbal lock) at $\\theta = 0, \\pi$: $\\det L_\\omega = -\\sin\\theta$.
    The identity orientation is singular; $\\theta = \\pi/2$ is a regular choice
    (`docs/model.md`, section 1.5 and correction 5).
    """

    name = "zxz"
    angle_names = ANGLE_NAMES["zxz"]
    regular_angles = (0.0, jnp.pi / 2, 0.0)
    singularity_name = "|sin(theta)|"

    def matrix(self, angles: Vector3) -> Matrix3:
        psi, theta, phi = angles
        return rot_z(psi) @ rot_x(theta) @ rot_z(phi)

    def angular_velocity_rows(
        self, angles: Vector3 | BodyCoordinates
    ) -> AngularVelocityRows:
        theta, phi = angles[1], angles[2]
        st, ct = jnp.sin(theta), jnp.cos(theta)
        sp, cp = jnp.sin(phi), jnp.cos(phi)
        return ((st * sp, cp, 0.0), (st * cp, -sp, 0.0), (ct, 0.0, 1.0))

    def regularity(self, angles: Vector3) -> Scalar:
        return jnp.sin(angles[1])
