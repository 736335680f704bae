"""Static equilibrium: hand-computed spring deflections, linear solve of Appendix A,
global balance of the reactions, and the under-constrained error."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import UPRIGHT

import elasticoop as eo

G = 9.81
K1 = np.array([800.0, 900.0, 1000.0, 20.0, 25.0, 30.0])
K2 = np.array([700.0, 850.0, 950.0, 22.0, 18.0, 26.0])
MASSES = (2.0, 0.3, 0.25)
GRASPS = np.zeros((3, 6), bool)
GRASPS[1:] = True


def bodies():
    return [
        eo.RigidBody(MASSES[0], (0.02, 0.15, 0.16)),
        eo.RigidBody(MASSES[1], (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(MASSES[2], (1.5e-3, 2.5e-3, 3e-3)),
    ]


def zero_length_model():
    """Two linear springs (rest length 0) from the grasps to the object."""
    conns = [eo.Connection(0, 1, K1, np.zeros(6)), eo.Connection(0, 2, K2, np.zeros(6))]
    return eo.MobileModel(bodies(), conns, gravity=G)


def configuration():
    up = UPRIGHT["zxz"]
    return jnp.array(
        [
            [0.0, 0.0, 1.0, *up],
            [-0.5, 0.0, 1.0, up[0] + 0.1, up[1], up[2] - 0.05],
            [0.5, 0.1, 1.2, up[0] - 0.02, up[1] + 0.03, up[2]],
        ]
    )


@pytest.mark.slow
def test_hanging_object_matches_hand_computed_deflection():
    y = configuration()
    eq = eo.static_equilibrium(zero_length_model(), y, GRASPS)
    # sum_i C_i (r_i - r_0) = -m_0 g e_z  =>  r_0 = (sum C_i r_i - m_0 g e_z) / sum C_i
    weight = np.array([0.0, 0.0, -MASSES[0] * G])
    r0 = (K1[:3] * y[1, :3] + K2[:3] * y[2, :3] + weight) / (K1[:3] + K2[:3])
    np.testing.assert_allclose(eq.y[0, :3], r0, rtol=0, atol=1e-12)
    # Euler-angle springs (rest angles 0): c1 (A_0 - A_1) + c2 (A_0 - A_2) = 0
    a0 = (K1[3:] * y[1, 3:] + K2[3:] * y[2, 3:]) / (K1[3:] + K2[3:])
    np.testing.assert_allclose(eq.y[0, 3:], a0, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(eq.y[1:], y[1:])
    assert eq.stable and float(eq.residual) < 1e-10


@pytest.mark.slow
def test_reactions_carry_the_whole_weight():
    eq = eo.static_equilibrium(zero_length_model(), configuration(), GRASPS)
    np.testing.assert_allclose(jnp.sum(eq.reaction[:, 2]), G * sum(MASSES), rtol=1e-12)
    np.testing.assert_allclose(jnp.sum(eq.reaction[:, :2], axis=0), 0.0, atol=1e-10)
    assert float(jnp.max(jnp.abs(eq.reaction[0]))) == 0.0


def test_links_with_rest_length_hang_stably():
    """Rest-length links are stiff only along themselves at the unloaded state
    (rank 4m): the weight loads them and the loaded equilibrium is unique."""
    y = configuration()
    model = eo.MobileModel(
        bodies(),
        [eo.Connection(0, 1, K1, np.zeros(6)), eo.Connection(0, 2, K2, np.zeros(6))],
        gravity=G,
    ).with_unloaded_state(y)
    eq = eo.static_equilibrium(model, y, GRASPS)
    assert eq.stable and float(eq.residual) < 1e-9
    assert float(eq.y[0, 2]) < float(y[0, 2])  # it sags


def test_immobile_model_is_a_linear_solve():
    y0 = configuration()
    rng = np.random.default_rng(1)
    a = rng.normal(size=(18, 12))
    K = 100 * a @ a.T  # rank 12 = 6m
    model = eo.ImmobileModel(bodies(), K, np.zeros((18, 18)), y0, gravity=G)
    forces = rng.normal(size=(2, 6))
    mask = np.zeros((3, 6), bool)
    mask[2] = True
    y_guess = y0.at[2].add(0.01)
    eq = eo.static_equilibrium(model, y_guess, mask, forces)
    rhs = np.zeros(18)
    rhs[2::6] = -G * np.repeat(MASSES, 1)
    rhs[6:] += forces.reshape(-1)
    free = ~mask.reshape(-1)
    dy_p = np.asarray(y_guess - y0).reshape(-1)[~free]
    dy_f = np.linalg.solve(
        K[np.ix_(free, free)], rhs[free] - K[np.ix_(free, ~free)] @ dy_p
    )
    np.testing.assert_allclose(
        np.asarray(eq.y - y0).reshape(-1)[free], dy_f, rtol=0, atol=1e-12
    )


@pytest.mark.parametrize(
    "mask_rows, missing",
    [((), 6), (((1, slice(0, 3)),), 3), (((1, slice(0, 6)),), 0)],
)
@pytest.mark.slow
def test_under_constrained_error_counts_missing_constraints(mask_rows, missing):
    mask = np.zeros((3, 6), bool)
    for body, cols in mask_rows:
        mask[body, cols] = True
    model = zero_length_model()
    if missing == 0:
        assert eo.static_equilibrium(model, configuration(), mask).stable
        return
    word = "constraints are" if missing > 1 else "constraint is"
    with pytest.raises(ValueError, match=f"{missing} {word} missing"):
        eo.static_equilibrium(model, configuration(), mask)


def test_bad_equilibrium_inputs():
    model = zero_length_model()
    with pytest.raises(ValueError, match=r"prescribed must be a bool array"):
        eo.static_equilibrium(model, configuration(), np.ones((2, 6), bool))
    with pytest.raises(ValueError, match="nothing to solve"):
        eo.static_equilibrium(model, configuration(), np.ones((3, 6), bool))
    with pytest.raises(ValueError, match=r"forces must give shape \(2, 6\)"):
        eo.static_equilibrium(model, configuration(), GRASPS, np.zeros((4, 6)))


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"max_steps": 10**30}, r"max_steps .* at most 2147483647, got an integer"),
        ({"rtol": -1.0}, r"static_equilibrium.rtol must be a positive number"),
        ({"atol": float("nan")}, r"static_equilibrium.atol must be a positive number"),
    ],
)
def test_bad_equilibrium_settings_are_named(settings, message):
    """Settings are checked as the simulation's are (before: `max_steps=10**30` ended
    in an `OverflowError`, a negative or NaN tolerance reached the solver)."""
    with pytest.raises(ValueError, match=message):
        eo.static_equilibrium(zero_length_model(), configuration(), GRASPS, **settings)


def test_a_traced_model_is_sent_to_rest_state():
    """`static_equilibrium` reports ranks and missing constraints, which need
    concrete values: under `grad` it names the traceable `rest_state` instead of
    failing on a tracer's conversion to NumPy."""
    model = zero_length_model()

    def lowest_point(gravity):
        changed = eqx.tree_at(lambda m: m.gravity, model, gravity)
        return eo.static_equilibrium(changed, configuration(), GRASPS).y[0, 2]

    with pytest.raises(ValueError, match=r"traced model .* elasticoop.rest_state"):
        jax.grad(lowest_point)(jnp.asarray(G))
