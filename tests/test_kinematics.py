"""Autodiff mass matrix and velocity terms against the appendix's closed forms."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    CONVENTIONS,
    zxz_dT_dy,
    zxz_mass_matrix,
    zxz_w_angular,
    zxz_wdot_ydot,
)

import elasticoop as eo
from elasticoop import _lagrange

# Autodiff and closed forms agree to rounding; 1e-12 relative leaves ample margin.
CLOSED_FORM_RTOL = 1e-12


def _random_body_and_state(rng):
    m = rng.uniform(0.5, 3.0)
    A, B = rng.uniform(0.2, 2.0, 2)
    C = rng.uniform(abs(A - B) + 0.05, A + B - 0.05)
    y = rng.normal(size=6)
    y[4] = rng.uniform(0.3, np.pi - 0.3)
    return m, (A, B, C), y, rng.normal(size=6)


def _rel(a, b):
    return np.max(np.abs(np.asarray(a) - np.asarray(b))) / max(
        np.max(np.abs(b)), 1e-300
    )


@pytest.mark.parametrize("seed", range(6))
def test_zxz_mass_matrix_and_velocity_terms_match_appendix(seed):
    rng = np.random.default_rng(seed)
    m, (A, B, C), y, v = _random_body_and_state(rng)
    model = eo.MobileModel([eo.RigidBody(m, (A, B, C))])
    W = eo.mass_matrix(model, jnp.array(y)[None])[0]
    c = eo.velocity_terms(model, jnp.array(y)[None], jnp.array(v)[None])[0]
    theta, phi = y[4], y[5]
    W_ref = zxz_mass_matrix(m, A, B, C, theta, phi)
    assert _rel(W, W_ref) < CLOSED_FORM_RTOL
    wdot = zxz_wdot_ydot(A, B, C, theta, phi, *v[3:])
    dT = zxz_dT_dy(A, B, C, theta, phi, *v[3:])
    assert _rel(c, wdot - dT) < CLOSED_FORM_RTOL
    # and the angular rows of w_i as printed (with the sign fix)
    assert _rel(c[3:], zxz_w_angular(A, B, C, theta, phi, *v[3:])) < CLOSED_FORM_RTOL
    # dT/dy alone: gradient of the kinetic energy
    grad = jax.grad(model.kinetic_energy)(jnp.array(y)[None], jnp.array(v)[None])[0]
    assert _rel(grad, dT) < CLOSED_FORM_RTOL


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_angular_velocity_matrix_matches_rotation_derivative(convention):
    """omega_body = vee(R^T dR/dt), R differentiated by autodiff."""
    rot = eo.get_rotation(convention)
    rng = np.random.default_rng(1)
    for _ in range(5):
        a = jnp.array(rng.normal(size=3))
        adot = jnp.array(rng.normal(size=3))
        R, Rdot = jax.jvp(rot.matrix, (a,), (adot,))
        skew = R.T @ Rdot
        omega = jnp.array([skew[2, 1], skew[0, 2], skew[1, 0]])
        np.testing.assert_allclose(
            rot.angular_velocity(a, adot), omega, rtol=0, atol=1e-13
        )
        np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-13)


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_mass_matrix_determinant_vanishes_only_at_singularity(convention):
    rot = eo.get_rotation(convention)
    m, inertia = 1.5, (0.3, 0.5, 0.6)
    model = eo.MobileModel([eo.RigidBody(m, inertia)], convention=convention)
    a = jnp.array([0.3, 0.7, -0.4])
    W = eo.mass_matrix(model, jnp.concatenate([jnp.zeros(3), a])[None])[0]
    expected = m**3 * np.prod(inertia) * rot.regularity(a) ** 2
    np.testing.assert_allclose(np.linalg.det(W), expected, rtol=1e-12)


@pytest.mark.parametrize("convention", CONVENTIONS)
def test_accelerations_solve_the_autodiff_mass_matrix(convention):
    """The free dynamics assembles W yddot = G + F - w in the structure of T
    (blocks diag(m 1, L^T I L) inverted through L; velocity terms
    L^T (I Ldot a' + omega x I omega)) and the connections (per-connection
    gradients gathered per body): the same W as the autodiff Hessian of T
    (`mass_matrix`), the same w as the autodiff of T and of Pi and R over the
    whole state (`velocity_terms`, `elastic_forces`, `damping_forces`), and the
    accelerations solve W yddot = G + F - w with that W, all to rounding."""
    rng = np.random.default_rng(5)
    bodies, y = [], []
    for _ in range(4):
        m, inertia, yi, _ = _random_body_and_state(rng)
        bodies.append(eo.RigidBody(m, inertia))
        if convention == "rpy":  # pitch away from +-pi/2
            yi[4] = rng.uniform(-1.2, 1.2)
        y.append(yi)
    connections = [
        eo.Connection(i, j, rng.uniform(1.0, 9.0, 6), rng.uniform(0.1, 0.9, 6))
        for i, j in ((0, 1), (0, 2), (1, 3))
    ]
    y = jnp.asarray(np.array(y))
    model = eo.MobileModel(bodies, connections, convention=convention)
    model = model.with_unloaded_state(y + 0.05 * rng.normal(size=(4, 6)))
    ydot = jnp.asarray(rng.normal(size=(4, 6)))
    applied = jnp.asarray(rng.normal(size=(4, 6)))
    blocks, b, _ = _lagrange._balance(model, y, ydot, applied)
    independent = (
        model.gravity_forces()
        + applied
        - eo.velocity_terms(model, y, ydot)
        - eo.elastic_forces(model, y)
        - eo.damping_forces(model, y, ydot)
    )
    assert _rel(jnp.stack(b, -1), independent) < CLOSED_FORM_RTOL
    W = eo.mass_matrix(model, y)
    for i in range(6):
        for k in range(6):
            entry = np.broadcast_to(np.asarray(blocks.entry(i, k)), (4,))
            assert _rel(entry, W[:, i, k]) < CLOSED_FORM_RTOL, (i, k)
    yddot, _ = eo.accelerations(model, y, ydot, applied)
    rhs = jnp.stack(b, -1)
    residual = jnp.einsum("bij,bj->bi", W, yddot) - rhs
    assert np.max(np.abs(residual)) < CLOSED_FORM_RTOL * np.max(np.abs(rhs))
