"""`rest_state`: the static equilibrium as a traceable function of the model's
parameters, checked against `static_equilibrium` (values) and central finite
differences (derivatives with respect to a stiffness, forward and reverse mode)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import UPRIGHT

import elasticoop as eo
from elasticoop._analysis import rest_state
from elasticoop._compile_options import fast_compile_jit

G = 9.81
K1 = np.array([800.0, 900.0, 1000.0, 20.0, 25.0, 30.0])
K2 = np.array([700.0, 850.0, 950.0, 22.0, 18.0, 26.0])
# commanded forces on the contact bodies (numbers): they do not enter the object's
# balance while the contact bodies are held, but do where a contact body is free
FORCES = np.array([[0.0, 0.0, 3.0, 0.0, 0.0, 0.0], [0.5, -0.2, 2.5, 0.0, 0.0, 0.0]])


def configuration():
    up = UPRIGHT["zxz"]
    return jnp.array(
        [
            [0.0, 0.0, 1.0, *up],
            [-0.5, 0.0, 1.0, up[0] + 0.1, up[1], up[2] - 0.05],
            [0.5, 0.1, 1.2, up[0] - 0.02, up[1] + 0.03, up[2]],
        ]
    )


def model(k1=K1):
    """Two links with rest length from the grasps to the object: the weight loads
    them nonlinearly (the deflection's direction changes with the sag)."""
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    conns = [
        eo.Connection(0, 1, jnp.asarray(k1), np.zeros(6)),
        eo.Connection(0, 2, K2, np.zeros(6)),
    ]
    return eo.MobileModel(bodies, conns, gravity=G).with_unloaded_state(configuration())


def with_kz(kz):
    """The model with the first link's z stiffness `kz` (a traced value)."""
    base = model()
    return eqx.tree_at(lambda m: m.stiffness, base, base.stiffness.at[0, 2].set(kz))


# free: the object, and the second contact body's x and y (where its commanded
# force enters the balance)
MASK = np.zeros((3, 6), bool)
MASK[1] = True
MASK[2, 2:] = True
DEFAULT_HELD = eo._analysis.contact_bodies_held(3)


def rest(kz):
    return rest_state(with_kz(kz), configuration(), FORCES, MASK)


# compiled once for the module, with the library's fast-compile options
rest_many = fast_compile_jit(jax.vmap(rest))
rest_default_many = fast_compile_jit(
    jax.vmap(lambda k: rest_state(with_kz(k), configuration()))
)


@pytest.mark.slow
@pytest.mark.parametrize("held", [None, MASK])
def test_rest_state_is_the_static_equilibrium_under_jit_and_vmap(held):
    kz = jnp.array([600.0, 1400.0])
    ys = (rest_default_many if held is None else rest_many)(kz)
    mask = DEFAULT_HELD if held is None else held
    forces = None if held is None else FORCES
    for k, y in zip(kz, ys):
        expected = eo.static_equilibrium(with_kz(k), configuration(), mask, forces)
        np.testing.assert_allclose(y, expected.y, rtol=0, atol=1e-10)
        assert float(y[0, 2]) < 1.0  # it sags


@pytest.mark.slow
def test_rest_state_derivative_matches_finite_differences():
    """d Y_rest / d k (implicit function theorem) in forward and reverse mode, against
    central differences of `static_equilibrium` (its own solver, converged tightly)."""
    k0, h = 1000.0, 1.0
    fd = (
        eo.static_equilibrium(with_kz(k0 + h), configuration(), MASK, FORCES).y
        - eo.static_equilibrium(with_kz(k0 - h), configuration(), MASK, FORCES).y
    ) / (2 * h)
    assert float(jnp.max(jnp.abs(fd))) > 1e-8  # the rest state moves with k
    weights = jnp.arange(18.0).reshape(3, 6)

    @fast_compile_jit
    def derivatives(k):
        _, tangent = jax.jvp(rest, (k,), (jnp.ones_like(k),))
        jac = jax.jacfwd(rest)(k)
        grad = jax.grad(lambda k: jnp.sum(weights * rest(k)))(k)
        return tangent, jac, grad

    tangent, jac, grad = derivatives(jnp.asarray(k0))
    np.testing.assert_allclose(tangent, fd, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(jac, fd, rtol=1e-5, atol=1e-12)
    np.testing.assert_allclose(grad, jnp.sum(weights * fd), rtol=1e-5)


def test_rest_state_without_convergence():
    with pytest.raises(Exception, match="did not converge"):
        jax.block_until_ready(rest_state(model(), configuration(), max_steps=1))
    y = rest_state(model(), configuration(), max_steps=1, throw=False)
    assert bool(jnp.all(jnp.isnan(y)))


def test_bad_rest_state_inputs():
    with pytest.raises(ValueError, match="nothing to solve"):
        rest_state(model(), configuration(), held=np.ones((3, 6), bool))
    with pytest.raises(ValueError, match=r"forces must give shape \(2, 6\)"):
        rest_state(model(), configuration(), np.zeros((4, 6)))
    with pytest.raises(ValueError, match=r"held must be a bool array"):
        rest_state(model(), configuration(), held=np.ones((2, 6), bool))
