"""jax.grad against finite differences; jax.vmap against a Python loop."""

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
from helpers import three_body_model, three_body_state

import elasticoop as eo

# Central differences with relative step 1e-4 (truncation ~1e-8, rounding of the
# loss ~1e-16 / 1e-4): 1e-5 relative agreement is the requirement.
GRAD_RTOL = 1e-5
VMAP_RTOL = 1e-12

TS = jnp.linspace(0.0, 0.2, 21)
MODEL = three_body_model()
Y0 = three_body_state().at[1, :3].add(jnp.array([-0.01, 0.005, 0.01]))
Y0 = Y0.at[2, 3:].add(jnp.array([0.02, -0.01, 0.03]))
YDOT0 = jnp.zeros_like(Y0).at[0, :3].set(jnp.array([0.1, 0.0, 0.2]))
TARGET = eo.simulate(MODEL, Y0, YDOT0, TS).y * 1.01


def _with_params(stiffness, damping):
    return eqx.tree_at(lambda m: (m.stiffness, m.damping), MODEL, (stiffness, damping))


@jax.jit
def loss(params):
    stiffness, damping = params
    traj = eo.simulate(
        _with_params(stiffness, damping), Y0, YDOT0, TS, rtol=1e-12, atol=1e-14
    )
    return jnp.sum((traj.y - TARGET) ** 2)


def test_gradient_matches_central_differences():
    params = (MODEL.stiffness, MODEL.damping)
    grads = jax.grad(loss)(params)
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    gflat, _ = jax.flatten_util.ravel_pytree(grads)
    fd = np.zeros(flat.shape[0])
    for k in range(flat.shape[0]):
        h = 1e-4 * abs(float(flat[k]))
        e = jnp.zeros_like(flat).at[k].set(h)
        fd[k] = (loss(unravel(flat + e)) - loss(unravel(flat - e))) / (2 * h)
    assert flat.shape[0] == 24
    error = np.abs(np.asarray(gflat) - fd)
    # Relative to the gradient's size (max-norm): the adaptive solver's rounding
    # (~1e-16 of the loss) limits how well a finite difference resolves the entries
    # that are 1e-3 of the largest; those must still agree to 1e-3 of themselves.
    top = np.max(np.abs(fd))
    assert np.max(error) / top < GRAD_RTOL
    np.testing.assert_array_less(error, 1e-3 * np.abs(fd) + GRAD_RTOL * top)


def test_vmap_over_stiffness_and_damping_equals_loop():
    rng = np.random.default_rng(0)
    ks = MODEL.stiffness * jnp.array(rng.uniform(0.5, 1.5, size=(8, 2, 6)))
    ds = MODEL.damping * jnp.array(rng.uniform(0.5, 1.5, size=(8, 2, 6)))

    def run(k, d):
        return eo.simulate(_with_params(k, d), Y0, YDOT0, TS)

    batch = jax.jit(jax.vmap(run))(ks, ds)
    assert batch.y.shape == (8, len(TS), 3, 6)
    for b in range(8):
        single = run(ks[b], ds[b])
        for got, want in ((batch.y[b], single.y), (batch.ydot[b], single.ydot)):
            # relative to the array's scale (max-norm)
            gap = jnp.max(jnp.abs(got - want)) / jnp.max(jnp.abs(want))
            assert float(gap) < VMAP_RTOL
    assert np.all(np.asarray(batch.status) == 0)


def test_gradient_with_respect_to_masses_initial_state_and_forces():
    F = jnp.zeros((2, 6)).at[:, 2].set(12.0)

    def objective(mass, y0, force):
        model = eqx.tree_at(lambda m: m.bodies.mass, MODEL, mass)
        traj = eo.simulate(model, y0, YDOT0, TS, forces=force, rtol=1e-12, atol=1e-14)
        return jnp.sum(traj.y[-1, :, :3] ** 2)

    g_mass, g_y0, g_force = jax.grad(objective, argnums=(0, 1, 2))(
        MODEL.bodies.mass, Y0, F
    )
    h = 1e-6
    e = jnp.zeros(3).at[0].set(h)
    fd = (
        objective(MODEL.bodies.mass + e, Y0, F)
        - objective(MODEL.bodies.mass - e, Y0, F)
    ) / (2 * h)
    np.testing.assert_allclose(g_mass[0], fd, rtol=GRAD_RTOL)
    ey = jnp.zeros_like(Y0).at[0, 2].set(h)
    fd = (
        objective(MODEL.bodies.mass, Y0 + ey, F)
        - objective(MODEL.bodies.mass, Y0 - ey, F)
    ) / (2 * h)
    np.testing.assert_allclose(g_y0[0, 2], fd, rtol=GRAD_RTOL)
    ef = jnp.zeros_like(F).at[1, 2].set(h)
    fd = (
        objective(MODEL.bodies.mass, Y0, F + ef)
        - objective(MODEL.bodies.mass, Y0, F - ef)
    ) / (2 * h)
    np.testing.assert_allclose(g_force[1, 2], fd, rtol=GRAD_RTOL)
