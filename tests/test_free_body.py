"""A single torque-free asymmetric body against an independent quaternion solution."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_tight
from scipy.integrate import solve_ivp

import elasticoop as eo

MOMENTUM_RTOL = 1e-8
# Euler angles (`run_tight`: rtol 1e-12) vs quaternions (DOP853, rtol 1e-13): both
# ~1e-10.
ROTATION_ATOL = 1e-7

INERTIA = np.array([1.0, 2.0, 3.0])
OMEGA0 = np.array([0.4, -0.3, 2.0])  # mostly about the major axis: stays regular
START = {"zxz": np.array([0.3, 1.2, -0.4]), "rpy": np.array([0.2, 0.3, -0.5])}


def _quaternion_rotations(R0, ts):
    """Euler's equations I w' = (I w) x w and q' = q (x) (0, w)/2 by SciPy."""

    def rhs(t, s):
        q, w = s[:4], s[4:]
        wdot = np.cross(INERTIA * w, w) / INERTIA
        a, b, c, d = q
        qdot = 0.5 * np.array(
            [
                -b * w[0] - c * w[1] - d * w[2],
                a * w[0] + c * w[2] - d * w[1],
                a * w[1] - b * w[2] + d * w[0],
                a * w[2] + b * w[1] - c * w[0],
            ]
        )
        return np.concatenate([qdot, wdot])

    from scipy.spatial.transform import Rotation

    q0 = Rotation.from_matrix(R0).as_quat(scalar_first=True)
    sol = solve_ivp(
        rhs,
        (ts[0], ts[-1]),
        np.concatenate([q0, OMEGA0]),
        method="DOP853",
        t_eval=ts,
        rtol=1e-13,
        atol=1e-14,
    )
    quats = sol.y[:4].T
    quats = quats / np.linalg.norm(quats, axis=1, keepdims=True)
    return Rotation.from_quat(quats, scalar_first=True).as_matrix()


@pytest.mark.parametrize(
    "convention", ["zxz", pytest.param("rpy", marks=pytest.mark.slow)]
)
def test_torque_free_body(convention):
    rot = eo.get_rotation(convention)
    model = eo.MobileModel(
        [eo.RigidBody(1.7, INERTIA)], gravity=0.0, convention=convention
    )
    a0 = jnp.array(START[convention])
    rates0 = jnp.linalg.solve(rot.angular_velocity_matrix(a0), jnp.array(OMEGA0))
    y0 = jnp.concatenate([jnp.zeros(3), a0])[None]
    ydot0 = jnp.concatenate([jnp.array([0.1, 0.0, -0.2]), rates0])[None]
    traj = run_tight(model, y0, ydot0, 4.0)
    ts = np.asarray(traj.ts)

    angles, rates = traj.y[:, 0, 3:], traj.ydot[:, 0, 3:]
    R = jax.vmap(rot.matrix)(angles)
    omega = jax.vmap(rot.angular_velocity)(angles, rates)
    momentum = jnp.einsum("tij,tj->ti", R, INERTIA[None, :] * omega)
    drift = jnp.max(jnp.linalg.norm(momentum - momentum[0:1], axis=1))
    assert drift / jnp.linalg.norm(momentum[0]) < MOMENTUM_RTOL

    R_ref = _quaternion_rotations(np.asarray(R[0]), ts)
    assert np.max(np.abs(np.asarray(R) - R_ref)) < ROTATION_ATOL
    # the mass centre moves uniformly
    np.testing.assert_allclose(
        traj.y[:, 0, :3], np.outer(ts, [0.1, 0.0, -0.2]), atol=1e-12
    )
