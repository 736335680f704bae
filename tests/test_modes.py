"""Linearization and modes: sqrt(k/m), the Appendix A rotational inertia, a two-body
chain's analytic frequencies, and small motions of the nonlinear model."""

import jax
import jax.numpy as jnp
import matplotlib
import numpy as np
import pytest
import scipy.linalg
from helpers import UPRIGHT, hold, run_tight, three_body_model, zxz_mass_matrix

import elasticoop as eo

matplotlib.use("Agg")

K = np.array([800.0, 900.0, 1000.0, 20.0, 25.0, 30.0])
C = np.array([2.0, 1.5, 1.0, 0.02, 0.03, 0.01])
INERTIA = (0.02, 0.15, 0.16)


def spring_mass(angles):
    bodies = [eo.RigidBody(2.0, INERTIA), eo.RigidBody(0.3, (1e-3, 1e-3, 1e-3))]
    model = eo.MobileModel(bodies, [eo.Connection(0, 1, K, C)], gravity=0.0)
    y = jnp.array([[0.0, 0.0, 1.0, *angles], [0.0, 0.0, 1.0, *angles]])
    mask = np.zeros((2, 6), bool)
    mask[1] = True
    return eo.linearize(model, y, mask)


@pytest.mark.slow
def test_spring_mass_frequencies_and_damping():
    md = eo.modes(spring_mass(UPRIGHT["zxz"]))
    translation = np.sqrt(K[:3] / 2.0)
    np.testing.assert_allclose(np.sort(md.frequencies)[2:5], translation, rtol=1e-12)
    for k, w in enumerate(translation):
        mode = int(np.argmin(np.abs(md.frequencies - w)))
        np.testing.assert_allclose(md.damping_ratios[mode], C[k] / (2 * 2.0 * w))
    # state-space eigenvalues: -zeta w +- i w sqrt(1 - zeta^2)
    lam = md.eigenvalues[np.abs(np.abs(md.eigenvalues) - translation[0]) < 1e-6]
    np.testing.assert_allclose(-lam.real, C[0] / (2 * 2.0), rtol=1e-9)


@pytest.mark.parametrize("angles", [(0.3, 1.1, -0.4), (1.0, 0.7, 2.0)])
def test_rotational_frequencies_use_the_appendix_mass_matrix(angles):
    md = eo.modes(spring_mass(angles))
    W = zxz_mass_matrix(2.0, *INERTIA, angles[1], angles[2])
    expected = np.sqrt(scipy.linalg.eigh(np.diag(K), W, eigvals_only=True))
    np.testing.assert_allclose(md.frequencies, np.sort(expected), rtol=1e-10)


def test_two_body_chain_matches_analytic_frequencies():
    """ground -- ka -- body 1 -- kb -- body 0, per axis a 2-DOF chain."""
    ka = np.array([500.0, 600.0, 700.0, 10.0, 12.0, 14.0])
    kb = np.array([300.0, 200.0, 400.0, 6.0, 8.0, 5.0])
    m0, m1 = 1.5, 0.7
    bodies = [
        eo.RigidBody(m0, (0.01, 0.01, 0.01)),
        eo.RigidBody(m1, (0.01, 0.01, 0.01)),
        eo.RigidBody(1.0, (0.01, 0.01, 0.01)),
    ]
    conns = [eo.Connection(1, 2, ka, np.zeros(6)), eo.Connection(0, 1, kb, np.zeros(6))]
    model = eo.MobileModel(bodies, conns, gravity=0.0)
    up = UPRIGHT["zxz"]
    y = jnp.array([[0.0, 0.0, 1.0, *up]] * 3)
    mask = np.zeros((3, 6), bool)
    mask[2] = True
    md = eo.modes(eo.linearize(model, y, mask))
    expected = []
    for a, b in zip(ka[:3], kb[:3]):
        # det [[(a + b)/m1 - l, -b/m1], [-b/m0, b/m0 - l]] = 0
        tr, det = (a + b) / m1 + b / m0, a * b / (m0 * m1)
        disc = np.sqrt(tr**2 - 4 * det)
        expected += [np.sqrt((tr - disc) / 2), np.sqrt((tr + disc) / 2)]
    translational = [
        w
        for w, k in zip(md.frequencies, range(12))
        if md.names[np.argmax(np.abs(md.shapes[:, k]))][-1] in "xyz"
    ]
    np.testing.assert_allclose(np.sort(translational), np.sort(expected), rtol=1e-10)


@pytest.mark.slow
def test_linear_response_matches_nonlinear_simulation_for_small_amplitude():
    """A hanging object on two rest-length links (stiff only through the load it
    carries): the nonlinear and linear responses differ by O(eps^2)."""
    up = UPRIGHT["zxz"]
    y = jnp.array([[0.0, 0.0, 1.0, *up], [-0.5, 0.0, 1.0, *up], [0.5, 0.0, 1.0, *up]])
    bodies = [
        eo.RigidBody(2.0, INERTIA),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    conns = [eo.Connection(0, i, K, C) for i in (1, 2)]
    model = eo.MobileModel(bodies, conns).with_unloaded_state(y)
    grasps = np.zeros((3, 6), bool)
    grasps[1:] = True
    eq = eo.static_equilibrium(model, y, grasps)
    lin = eo.linearize(model, eq.y, grasps)
    ss = lin.state_space()
    held = hold(grasps, eq.y)
    direction = np.array([1.0, -0.5, 0.8, 2.0, -1.0, 1.5])
    errors = []
    for eps in (1e-3, 2e-3):
        q0 = eps * direction
        y0 = eq.y.at[0].add(q0)
        traj = run_tight(model, y0, jnp.zeros_like(y0), 0.5, prescribed=held)
        ts = np.asarray(traj.ts)
        x0 = np.concatenate([q0, np.zeros(6)])
        linear = scipy.linalg.expm(np.asarray(ss.A) * ts[:, None, None]) @ x0
        errors.append(
            np.max(np.abs(np.asarray(traj.y[:, 0] - eq.y[0:1]) - linear[:, :6]))
        )
        assert errors[-1] < 0.05 * eps
    # second-order agreement: doubling eps quadruples the difference
    assert 3.0 < errors[1] / errors[0] < 5.0


def test_state_space_table_and_plot():
    lin = spring_mass(UPRIGHT["zxz"])
    ss = lin.state_space()
    assert ss.A.shape == (12, 12) and ss.B.shape == (12, 12) and ss.D.shape == (6, 12)
    # A's eigenvalues are the modal ones
    np.testing.assert_allclose(
        np.sort(np.abs(np.linalg.eigvals(np.asarray(ss.A)))),
        np.sort(np.abs(eo.modes(lin).eigenvalues)),
        rtol=1e-10,
    )
    md = eo.modes(lin)
    table = md.table()
    assert "f [Hz]" in table and "object.x" in table and len(table.splitlines()) == 7
    fig = eo.plot_mode_shapes(md, count=3)
    axes = fig.axes
    assert len(axes) == 3
    assert axes[0].get_title().startswith("mode 1: f = ")
    assert axes[0].get_ylabel() == "relative amplitude"
    assert axes[-1].get_xlabel() == "free coordinate"
    import matplotlib.pyplot as plt

    plt.close(fig)


def test_full_configuration_from_free_vector():
    lin = spring_mass(UPRIGHT["zxz"])
    full = lin.to_full(jnp.arange(6.0))
    np.testing.assert_allclose(full[0] - lin.y_eq[0], jnp.arange(6.0))
    np.testing.assert_allclose(full[1], lin.y_eq[1])
    jax.block_until_ready(full)


def test_modes_of_a_model_that_is_not_linear_is_named():
    with pytest.raises(ValueError, match=r"modes takes a LinearModel, got MobileModel"):
        eo.modes(three_body_model())
