"""Closed-form motions: free fall and a two-body spring oscillator."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_tight, three_body_model, three_body_state

import elasticoop as eo

FREE_FALL_ATOL = 1e-10
OSCILLATOR_ATOL = 1e-8


@pytest.mark.parametrize(
    "convention", ["zxz", pytest.param("rpy", marks=pytest.mark.slow)]
)
def test_free_fall_without_deformation(convention):
    model = three_body_model(convention)
    y0 = three_body_state(convention)
    v0 = 0.7
    ydot0 = jnp.zeros_like(y0).at[:, 2].set(v0)
    traj = run_tight(model, y0, ydot0, 1.0)
    ts = traj.ts
    g = float(model.gravity)
    z = y0[None, :, 2] + v0 * ts[:, None] - 0.5 * g * ts[:, None] ** 2
    np.testing.assert_allclose(traj.y[:, :, 2], z, rtol=0, atol=FREE_FALL_ATOL)
    others = traj.y[:, :, [0, 1, 3, 4, 5]] - y0[None, :, [0, 1, 3, 4, 5]]
    assert float(jnp.max(jnp.abs(others))) < FREE_FALL_ATOL


def test_two_body_spring_is_a_reduced_mass_oscillator():
    m1, m2, c, rest, amp = 1.0, 0.5, 400.0, 0.3, 0.05
    bodies = [eo.RigidBody(m1, (0.1, 0.1, 0.1)), eo.RigidBody(m2, (0.2, 0.2, 0.2))]
    link = eo.Connection(
        0, 1, stiffness=(c, c, c, 5.0, 5.0, 5.0), damping=[0.0] * 6, rest_length=rest
    )
    model = eo.MobileModel(bodies, [link])  # gravity on: it moves both alike
    up = (0.0, np.pi / 2, 0.0)
    y0 = jnp.array([[0.0, 0.0, 2.0, *up], [-(rest + amp), 0.0, 2.0, *up]])
    traj = run_tight(model, y0, jnp.zeros_like(y0), 1.0)
    mu = m1 * m2 / (m1 + m2)
    expected = rest + amp * np.cos(np.sqrt(c / mu) * np.asarray(traj.ts))
    separation = traj.y[:, 0, 0] - traj.y[:, 1, 0]
    np.testing.assert_allclose(separation, expected, rtol=0, atol=OSCILLATOR_ATOL)
    # mass centre at rest horizontally, free fall vertically
    com = (m1 * traj.y[:, 0, 0] + m2 * traj.y[:, 1, 0]) / (m1 + m2)
    np.testing.assert_allclose(com, com[0], atol=1e-12)
