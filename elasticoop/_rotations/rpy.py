"""Tait-Bryan roll-pitch-yaw angles, regular at the identity."""

import jax.numpy as jnp

from .._custom_types import BodyCoordinates, Matrix3, Scalar, Vector3
from .._naming import ANGLE_NAMES
from .base import AbstractRotation, AngularVelocityRows, rot_x, rot_y, rot_z


class RPY(AbstractRotation):
    """Roll-pitch-yaw angles $(\\phi_r, \\theta_p, \\psi_y)$ (stored in this order),
    $R = R_z(\\psi_y) R_y(\\theta_p) R_x(\\phi_r)$.

    $$L_\\omega = \\begin{bmatrix}
        1 & 0 & -\\sin\\theta_p \\\\
        0 & \\cos\\phi_r & \\sin\\phi_r\\cos\\theta_p \\\\
        0 & -\\sin\\phi_r & \\cos\\phi_r\\cos\\theta_p \\end{bmatrix}$$

    Singular (gimbal lock) at pitch $= \\pm\\pi/2$: $\\det L_\\omega = \\cos\\theta_p$.
    """

    name = "rpy"
    angle_names = ANGLE_NAMES["rpy"]
    regular_angles = (0.0, 0.0, 0.0)
    singularity_name = "|cos(pitch)|"

    def matrix(self, angles: Vector3) -> Matrix3:
        roll, pitch, yaw = angles
        return rot_z(yaw) @ rot_y(pitch) @ rot_x(roll)

    def angular_velocity_rows(
        self, angles: Vector3 | BodyCoordinates
    ) -> AngularVelocityRows:
        roll, pitch = angles[0], angles[1]
        sr, cr = jnp.sin(roll), jnp.cos(roll)
        sp, cp = jnp.sin(pitch), jnp.cos(pitch)
        return ((1.0, 0.0, -sp), (0.0, cr, sr * cp), (0.0, -sr, cr * cp))

    def regularity(self, angles: Vector3) -> Scalar:
        return jnp.cos(angles[1])
