"""jax.grad against finite differences; jax.vmap against a Python loop."""

import functools

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_tight, three_body_model, three_body_state

# Central differences with relative step 1e-4 (truncation ~1e-8, rounding of the
# loss ~1e-16 / 1e-4): 1e-5 relative agreement is the requirement.
GRAD_RTOL = 1e-5
VMAP_RTOL = 1e-12

T_END = 0.2
MODEL = three_body_model()
Y0 = three_body_state().at[1, :3].add(jnp.array([-0.01, 0.005, 0.01]))
Y0 = Y0.at[2, 3:].add(jnp.array([0.02, -0.01, 0.03]))
YDOT0 = jnp.zeros_like(Y0).at[0, :3].set(jnp.array([0.1, 0.0, 0.2]))
NO_FORCE = jnp.zeros((2, 6))
LIFT = jnp.zeros((2, 6)).at[:, 2].set(12.0)
# What the gradients are taken with respect to: stiffness, damping, masses, initial
# state and applied forces.
PARAMS = (MODEL.stiffness, MODEL.damping, MODEL.bodies.mass, Y0, NO_FORCE)


def run(stiffness, damping, mass, y0, force, **options):
    """One run (`run_tight`, rtol 1e-12): the tests share its compilation."""
    model = eqx.tree_at(
        lambda m: (m.stiffness, m.damping, m.bodies.mass),
        MODEL,
        (stiffness, damping, mass),
    )
    return run_tight(model, y0, YDOT0, T_END, forces=force, **options)


def loss(params, weights, target):
    """sum(weights * (y - target)^2) over the samples, bodies and coordinates."""
    return jnp.sum(weights * (run(*params).y - target) ** 2)


# One compilation of the reverse pass for both gradient tests.
gradient = jax.jit(jax.grad(loss))


@functools.cache
def target():
    """The motion with every position 1 % further out."""
    return run(*PARAMS).y * 1.01


# Compiling the reverse pass through `simulate` takes about half a minute (once for
# both gradient tests).
@pytest.mark.slow
def test_gradient_matches_central_differences():
    ones = jnp.ones_like(target())
    grads = gradient(PARAMS, ones, target())
    rest = PARAMS[2:]
    flat, unravel = jax.flatten_util.ravel_pytree(PARAMS[:2])
    gflat, _ = jax.flatten_util.ravel_pytree(grads[:2])
    fd = np.zeros(flat.shape[0])
    for k in range(flat.shape[0]):
        h = 1e-4 * abs(float(flat[k]))
        e = jnp.zeros_like(flat).at[k].set(h)
        up = loss((*unravel(flat + e), *rest), ones, target())
        down = loss((*unravel(flat - e), *rest), ones, target())
        fd[k] = (up - down) / (2 * h)
    assert flat.shape[0] == 24
    error = np.abs(np.asarray(gflat) - fd)
    # Relative to the gradient's size (max-norm): the adaptive solver's rounding
    # (~1e-16 of the loss) limits how well a finite difference resolves the entries
    # that are 1e-3 of the largest; those must still agree to 1e-3 of themselves.
    top = np.max(np.abs(fd))
    assert np.max(error) / top < GRAD_RTOL
    np.testing.assert_array_less(error, 1e-3 * np.abs(fd) + GRAD_RTOL * top)


@pytest.mark.slow
def test_vmap_over_stiffness_and_damping_equals_loop():
    rng = np.random.default_rng(0)
    ks = MODEL.stiffness[None] * jnp.array(rng.uniform(0.5, 1.5, size=(8, 2, 6)))
    ds = MODEL.damping[None] * jnp.array(rng.uniform(0.5, 1.5, size=(8, 2, 6)))

    def run_kd(k, d, **options):
        return run(k, d, *PARAMS[2:], **options)

    # `vmap` of diffrax's loop with Tsit5, on which VMAP_RTOL was set (the batch
    # loop, `vmap`'s default, is compared with it at the runs' tolerance in
    # tests/test_batch_loop.py)
    run_kd = functools.partial(run_kd, solver="tsit5")
    batch = jax.jit(jax.vmap(functools.partial(run_kd, batch_loop=False)))(ks, ds)
    assert batch.y.shape == (8, *target().shape)
    for b in range(8):
        single = run_kd(ks[b], ds[b])
        for got, want in ((batch.y[b], single.y), (batch.ydot[b], single.ydot)):
            # relative to the array's scale (max-norm)
            gap = jnp.max(jnp.abs(got - want)) / jnp.max(jnp.abs(want))
            assert float(gap) < VMAP_RTOL
    assert np.all(np.asarray(batch.status) == 0)


@pytest.mark.slow
def test_gradient_with_respect_to_masses_initial_state_and_forces():
    # the objective sum |r_i(t_end)|^2: weights on the final positions only
    params = (*PARAMS[:4], LIFT)
    weights = jnp.zeros_like(target()).at[-1, :, :3].set(1.0)
    zero = jnp.zeros_like(target())

    def objective(mass, y0, force):
        return loss((*PARAMS[:2], mass, y0, force), weights, zero)

    _, _, g_mass, g_y0, g_force = gradient(params, weights, zero)
    mass = MODEL.bodies.mass
    h = 1e-6
    e = jnp.zeros(3).at[0].set(h)
    fd = (objective(mass + e, Y0, LIFT) - objective(mass - e, Y0, LIFT)) / (2 * h)
    np.testing.assert_allclose(g_mass[0], fd, rtol=GRAD_RTOL)
    ey = jnp.zeros_like(Y0).at[0, 2].set(h)
    fd = (objective(mass, Y0 + ey, LIFT) - objective(mass, Y0 - ey, LIFT)) / (2 * h)
    np.testing.assert_allclose(g_y0[0, 2], fd, rtol=GRAD_RTOL)
    ef = jnp.zeros_like(LIFT).at[1, 2].set(h)
    fd = (objective(mass, Y0, LIFT + ef) - objective(mass, Y0, LIFT - ef)) / (2 * h)
    np.testing.assert_allclose(g_force[1, 2], fd, rtol=GRAD_RTOL)
