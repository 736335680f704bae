"""Appendix B's potential and dissipation: invariances, closed forms, linearization."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_tight, three_body_model, three_body_state

import elasticoop as eo


def _random_state(seed, convention="zxz"):
    rng = np.random.default_rng(seed)
    y = three_body_state(convention) + 0.05 * rng.normal(size=(3, 6))
    return y, jnp.array(rng.normal(size=(3, 6)))


@pytest.mark.parametrize("seed", range(3))
def test_potential_and_dissipation_invariant_under_common_translation(seed):
    model = three_body_model()
    y, ydot = _random_state(seed)
    shift = jnp.zeros((3, 6)).at[:, :3].set(jnp.array([1.3, -0.7, 2.1]))
    np.testing.assert_allclose(
        model.potential(y + shift), model.potential(y), rtol=1e-13
    )
    np.testing.assert_allclose(
        model.dissipation(y + shift, ydot), model.dissipation(y, ydot), rtol=1e-13
    )
    # common velocity adds nothing to R either
    np.testing.assert_allclose(
        model.dissipation(y, ydot + shift), model.dissipation(y, ydot), rtol=1e-12
    )
    grad = eo.elastic_forces(model, y)
    assert float(jnp.max(jnp.abs(jnp.sum(grad[:, :3], axis=0)))) < 1e-12 * float(
        jnp.max(jnp.abs(grad))
    )
    # a common shift of the Euler angles is the other null mode (docs/model.md,
    # section 3.4)
    turn = jnp.zeros((3, 6)).at[:, 3:].set(jnp.array([0.2, -0.1, 0.3]))
    np.testing.assert_allclose(
        model.potential(y + turn), model.potential(y), rtol=1e-13
    )


@pytest.mark.parametrize("seed", range(2))
def test_restoring_forces_are_the_gradients_of_potential_and_dissipation(seed):
    """The forces of the equations of motion (per connection, gathered per body)
    against autodiff of Pi and R of the whole model, with rest lengths and rest
    angles set."""
    rng = np.random.default_rng(seed)
    model = eqx.tree_at(
        lambda m: m.rest_angles,
        three_body_model(),
        jnp.asarray(0.1 * rng.normal(size=(2, 3))),
    )
    assert float(jnp.min(model.rest_length)) > 0
    y, ydot = _random_state(seed)
    elastic, damping = model.restoring_forces(y, ydot)
    for got, want in (
        (elastic, jax.grad(model.potential)(y)),
        (damping, jax.grad(model.dissipation, argnums=1)(y, ydot)),
    ):
        scale = float(jnp.max(jnp.abs(want)))
        assert scale > 0
        np.testing.assert_allclose(got, want, rtol=1e-13, atol=1e-13 * scale)


def test_unloaded_state_has_zero_elastic_force():
    model = three_body_model()
    grad = eo.elastic_forces(model, three_body_state())
    assert float(jnp.max(jnp.abs(grad))) == 0.0


def test_potential_matches_appendix_pi_matrix_form():
    """2 Pi_ij = (Y_i - Y_j)^T pi_ij (Y_i - Y_j) with the appendix's pi_ij (zero
    rest angles), pi_ij = diag(c (1 - rho/|r_i - r_j|)^2, c^a)."""
    model = three_body_model()
    y, _ = _random_state(7)
    y = y.at[:, 3:].set(y[:, 3:] - y[0:1, 3:])  # any angles; rest angles are zero here
    total = 0.0
    for p, (i, j) in enumerate(np.asarray(model.pairs)):
        c = np.asarray(model.stiffness[p])
        rho = float(model.rest_length[p])
        d = np.asarray(y[i] - y[j])
        scale = (1 - rho / np.linalg.norm(d[:3])) ** 2
        pi = np.diag(np.concatenate([c[:3] * scale, c[3:]]))
        total += 0.5 * d @ pi @ d
    np.testing.assert_allclose(model.potential(y), total, rtol=1e-13)


def test_dissipation_uses_deflection_jacobian_closed_form():
    """R_ij with G(d) = (1 - rho/|d|) I + (rho/|d|) n n^T written out (docs/model.md,
    section 3.2)."""
    model = three_body_model()
    y, ydot = _random_state(3)
    total = 0.0
    for p, (i, j) in enumerate(np.asarray(model.pairs)):
        d = np.asarray(y[i, :3] - y[j, :3])
        rho = float(model.rest_length[p])
        length = np.linalg.norm(d)
        n = d / length
        G = (1 - rho / length) * np.eye(3) + (rho / length) * np.outer(n, n)
        rate = G @ np.asarray(ydot[i, :3] - ydot[j, :3])
        arate = np.asarray(ydot[i, 3:] - ydot[j, 3:])
        dd = np.asarray(model.damping[p])
        total += 0.5 * (rate @ (dd[:3] * rate) + arate @ (dd[3:] * arate))
    np.testing.assert_allclose(model.dissipation(y, ydot), total, rtol=1e-13)


def test_linearized_stiffness_is_rank_4m_and_stiff_along_links():
    model = three_body_model()
    y0 = three_body_state()
    lin = eo.linearize_mobile(model, y0)
    assert lin.stiffness_rank() == 4 * 2
    assert lin.n_prescribed() == 18 - 8
    assert model.stiffness_rank(y0) == 8
    # link 0-1 lies along x: its translational block is c_x n n^T = c_x e_x e_x^T
    block = np.asarray(lin.K[6:9, 6:9])
    expected = np.zeros((3, 3))
    expected[0, 0] = float(model.stiffness[0, 0])
    np.testing.assert_allclose(block, expected, atol=1e-9)
    np.testing.assert_allclose(
        np.asarray(lin.K[9:12, 9:12]),
        np.diag(np.asarray(model.stiffness[0, 3:])),
        atol=1e-12,
    )


def test_linearize_rejects_a_loaded_configuration():
    model = three_body_model()
    y = three_body_state().at[1, 0].add(0.01)
    with pytest.raises(ValueError, match="not an unloaded configuration"):
        eo.linearize_mobile(model, y)


@pytest.mark.slow
def test_linearized_and_mobile_models_agree_to_second_order():
    model = three_body_model(gravity=0.0)
    y0 = three_body_state()
    lin = eo.linearize_mobile(model, y0)
    direction = jnp.array(np.random.default_rng(5).normal(size=(3, 6)))

    def gap(eps):
        start = y0 + eps * direction
        a = run_tight(model, start, jnp.zeros_like(y0), 0.3)
        b = run_tight(lin, start, jnp.zeros_like(y0), 0.3)
        return float(jnp.max(jnp.abs(a.y - b.y)))

    e1, e2 = gap(1e-3), gap(5e-4)
    assert e1 < 1e-3 * 1e-3 * 50  # O(eps^2) with a modest constant
    assert 3.5 < e1 / e2 < 4.6  # halving eps quarters the gap


def test_immobile_model_potential_and_dissipation():
    model = three_body_model()
    lin = eo.linearize_mobile(model, three_body_state())
    y, ydot = _random_state(11)
    dy = (y - lin.y0).reshape(-1)
    np.testing.assert_allclose(lin.potential(y), 0.5 * dy @ lin.K @ dy, rtol=1e-13)
    v = ydot.reshape(-1)
    np.testing.assert_allclose(
        lin.dissipation(y, ydot), 0.5 * v @ lin.D @ v, rtol=1e-13
    )
    np.testing.assert_allclose(
        eo.elastic_forces(lin, y).reshape(-1), lin.K @ dy, rtol=1e-12, atol=1e-12
    )
