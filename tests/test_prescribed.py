"""Prescribed coordinates: reactions against free fall, inverse dynamics, momentum
and energy balances; SplineMotion; vmap and grad through a driven run."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import (
    SAMPLES,
    TIGHT,
    Wave,
    run_tight,
    three_body_model,
    three_body_state,
)

import elasticoop as eo

# The output times of `run_tight` over one second.
TS = jnp.linspace(0.0, 1.0, SAMPLES)
CONTACTS = np.zeros((3, 6), bool)
CONTACTS[1:] = True


class Ballistic(eo.AbstractMotion):
    """Every body translating together in free fall: springs and dampers idle."""

    y0: jax.Array
    v: jax.Array
    g: float = 9.81

    def __call__(self, t):
        fall = jnp.zeros(6).at[2].set(-0.5 * self.g * t**2)
        return self.y0 + t * self.v[None, :] + fall[None, :]


def wave(scale=1.0):
    """Grasps swaying about their initial poses (positions and angles)."""
    amp = np.zeros((3, 6))
    amp[1] = (0.02, 0.01, 0.03, 0.05, 0.04, -0.03)
    amp[2] = (-0.015, 0.02, 0.025, -0.02, 0.03, 0.04)
    return Wave(three_body_state(), jnp.asarray(scale * amp))


@pytest.fixture(scope="module")
def model():
    return three_body_model()


@pytest.fixture(scope="module")
def driven(model):
    motion = eo.PrescribedMotion(CONTACTS, wave())
    y0 = three_body_state()
    return run_tight(model, y0, jnp.zeros_like(y0), 1.0, prescribed=motion)


@pytest.mark.slow  # its own compilation (every coordinate prescribed)
def test_free_fall_needs_no_reaction(model):
    y0 = three_body_state()
    v = jnp.array([0.3, -0.2, 1.0, 0.0, 0.0, 0.0])
    motion = eo.PrescribedMotion(np.ones((3, 6), bool), Ballistic(y0, v))
    traj = run_tight(model, y0, jnp.zeros_like(y0), 1.0, prescribed=motion)
    weight = 9.81 * float(jnp.sum(model.bodies.mass))
    assert float(jnp.max(jnp.abs(traj.reaction))) < 1e-12 * weight
    np.testing.assert_allclose(traj.y[-1, :, 2], y0[:, 2] + 1.0 - 0.5 * 9.81)


def test_prescribed_entries_follow_the_motion_exactly(driven):
    motion = wave()
    expected = jax.vmap(motion)(TS)
    np.testing.assert_allclose(driven.y[:, 1:], expected[:, 1:], rtol=0, atol=1e-15)
    velocity = jax.vmap(lambda t: jax.jvp(motion, (t,), (1.0,))[1])(TS)
    np.testing.assert_allclose(driven.ydot[:, 1:], velocity[:, 1:], rtol=0, atol=1e-14)
    assert float(jnp.max(jnp.abs(driven.reaction[:, 0]))) == 0.0


# Its own compilation; test_inverse_dynamics_inverts_the_accelerations checks the
# inverse dynamics in the fast tests.
@pytest.mark.slow
def test_round_trip_forward_inverse_forward(model, driven):
    """Drive the contact bodies with the forces `inverse_dynamics` says they need
    for the prescribed accelerations: the free run reproduces the driven one."""
    motion = wave()

    def needed(t, y, ydot):
        accel = jax.jvp(lambda s: jax.jvp(motion, (s,), (1.0,))[1], (t,), (1.0,))[1]
        return eo.inverse_dynamics(model, y, ydot, accel)[1:]

    y0 = driven.y[0]
    forward = eo.simulate(model, y0, driven.ydot[0], TS, forces=needed, **TIGHT)
    scale = float(jnp.max(jnp.abs(driven.y)))
    np.testing.assert_allclose(forward.y, driven.y, rtol=0, atol=1e-8 * scale)
    forces = jax.vmap(needed)(TS, forward.y, forward.ydot)
    peak = float(jnp.max(jnp.abs(driven.reaction)))
    np.testing.assert_allclose(forces, driven.reaction[:, 1:], rtol=0, atol=1e-8 * peak)


def test_momentum_balance(model, driven):
    """Internal forces cancel: dP/dt = sum of reactions + weights (translation)."""
    mass = model.bodies.mass[None, :, None]
    momentum = np.asarray(jnp.sum(mass * driven.ydot[:, :, :3], axis=1))
    external = np.asarray(
        jnp.sum(driven.reaction[:, :, :3] + model.gravity_forces()[None, :, :3], 1)
    )
    h = float(TS[1] - TS[0])
    # composite Simpson over pairs of intervals
    integral = h / 3 * (external[:-2:2] + 4 * external[1:-1:2] + external[2::2])
    np.testing.assert_allclose(
        np.cumsum(integral, axis=0),
        momentum[2::2] - momentum[0],
        rtol=0,
        atol=1e-6 * np.max(np.abs(momentum)),
    )


def test_energy_balance_includes_reaction_work(driven):
    scale = float(jnp.max(jnp.abs(driven.work)))
    assert float(jnp.max(jnp.abs(driven.energy_residual()))) < 1e-7 * scale


@pytest.mark.slow  # compiles the batched run; test_transforms checks vmap fast
def test_vmap_over_motion_parameters(model, driven):
    y0 = three_body_state()
    scales = jnp.array([1.0, 0.5])

    def run(scale):
        motion = eo.PrescribedMotion(CONTACTS, wave(1.0))
        motion = eqx.tree_at(
            lambda p: p.motion.amplitude, motion, scale * wave().amplitude
        )
        return run_tight(
            model, y0, jnp.zeros_like(y0), 1.0, prescribed=motion, throw=False
        ).reaction

    batch = jax.vmap(run)(scales)
    np.testing.assert_allclose(batch[0], driven.reaction, rtol=0, atol=1e-9)
    half = run_tight(
        model,
        y0,
        jnp.zeros_like(y0),
        1.0,
        prescribed=eo.PrescribedMotion(CONTACTS, wave(0.5)),
    )
    np.testing.assert_allclose(batch[1], half.reaction, rtol=0, atol=1e-9)


@pytest.mark.slow  # reverse mode through a driven run; test_transforms: free runs
def test_reaction_gradient_matches_finite_differences(model):
    y0 = three_body_state()
    ts = jnp.linspace(0.0, 0.3, 4)
    motion = eo.PrescribedMotion(CONTACTS, wave())

    def loss(stiffness):
        m = eqx.tree_at(lambda m: m.stiffness, model, stiffness)
        traj = eo.simulate(
            m, y0, jnp.zeros_like(y0), ts, prescribed=motion, rtol=1e-10, atol=1e-12
        )
        return jnp.sum(traj.reaction[-1] ** 2)

    k = model.stiffness
    grad = jax.grad(loss)(k)
    direction = jnp.asarray(np.random.default_rng(0).normal(size=k.shape)) * k
    step = 1e-5
    fd = (loss(k + step * direction) - loss(k - step * direction)) / (2 * step)
    np.testing.assert_allclose(jnp.sum(grad * direction), fd, rtol=1e-5)


def test_spline_motion():
    ts = np.linspace(0.0, 2.0, 201)
    y = np.zeros((ts.size, 1, 6))
    y[:, 0, 0] = np.sin(3 * ts)
    y[:, 0, 1] = 2.0 + 0.5 * ts  # linear: reproduced exactly by the natural spline
    spline = eo.SplineMotion(ts, y)
    # knots are interpolated exactly
    np.testing.assert_allclose(jax.vmap(spline)(jnp.asarray(ts)), y, atol=1e-14)
    t = jnp.linspace(0.3, 1.7, 57)
    values = jax.vmap(spline)(t)
    np.testing.assert_allclose(values[:, 0, 0], np.sin(3 * t), atol=1e-7)
    np.testing.assert_allclose(values[:, 0, 1], 2.0 + 0.5 * t, atol=1e-13)
    # C2: the second derivative is continuous across a knot
    motion = eo.PrescribedMotion(np.ones((1, 6), bool), spline)
    state = jax.jit(lambda t: motion.state(t))  # one compilation for three times
    knot = float(ts[100])
    left = state(knot - 1e-9)[2][0, 0]
    right = state(knot + 1e-9)[2][0, 0]
    assert abs(float(left - right)) < 1e-6
    np.testing.assert_allclose(state(1.0)[2][0, 0], -9 * np.sin(3.0), rtol=2e-3)


@pytest.mark.parametrize(
    "make, match",
    [
        (lambda: eo.PrescribedMotion(np.ones((3, 5), bool), wave()), "shape"),
        (lambda: eo.PrescribedMotion(np.ones((3, 6)), wave()), "bool"),
        (lambda: eo.PrescribedMotion(CONTACTS, 3.0), "callable"),
        (lambda: eo.SplineMotion([0.0, 1.0, 0.5], np.zeros((3, 3, 6))), "increasing"),
        (lambda: eo.SplineMotion([0.0, 1.0], np.zeros((3, 3, 6))), "SplineMotion.y"),
    ],
)
def test_bad_motion_inputs(make, match):
    with pytest.raises(ValueError, match=match):
        make()


def test_bad_prescribed_inputs(model):
    y0 = three_body_state()
    zero = jnp.zeros_like(y0)
    with pytest.raises(ValueError, match=r"mask must have shape \(3, 6\)"):
        eo.simulate(
            model, y0, zero, TS, prescribed=eo.PrescribedMotion(CONTACTS[1:], wave())
        )
    with pytest.raises(ValueError, match="prescribes no coordinate"):
        eo.simulate(
            model,
            y0,
            zero,
            TS,
            prescribed=eo.PrescribedMotion(CONTACTS & False, wave()),
        )
    short = eo.SplineMotion([0.0, 0.5], jnp.stack([y0, y0]))
    with pytest.raises(ValueError, match="only cover"):
        eo.simulate(
            model, y0, zero, TS, prescribed=eo.PrescribedMotion(CONTACTS, short)
        )
    with pytest.raises(ValueError, match="PrescribedMotion"):
        eo.simulate(model, y0, zero, TS, prescribed=CONTACTS)


def _random_state(seed):
    rng = np.random.default_rng(seed)
    y = three_body_state() + 0.05 * rng.standard_normal((3, 6))
    return y, rng.standard_normal((3, 6)), rng.standard_normal((3, 6))


def test_empty_prescribed_mask_gives_exactly_the_free_accelerations():
    """One assembly of W Y'' + w = G + F: with nothing prescribed the constrained
    solve is the free one, bit for bit, and the reactions vanish."""
    model = three_body_model()
    y, ydot, applied = _random_state(0)
    nothing, yddot_p = np.zeros((3, 6), bool), jnp.full((3, 6), 7.0)
    # Both compiled, as `simulate` runs them (`accelerations` always is; evaluated
    # op by op, the constrained solve would round differently from any program).
    free, damping = eo.accelerations(model, y, ydot, applied)
    yddot, damping_c, reaction = jax.jit(
        lambda y, v, f: eo.constrained_accelerations(model, y, v, f, nothing, yddot_p)
    )(y, ydot, applied)
    np.testing.assert_array_equal(yddot, free)
    np.testing.assert_array_equal(damping_c, damping)
    np.testing.assert_array_equal(reaction, 0.0)


def test_inverse_dynamics_inverts_the_accelerations():
    """The forces behind the free accelerations are the applied ones, at a state
    (`inverse_dynamics`) and along a series of states (`inverse_dynamics_series`)."""
    model = three_body_model()
    states = [_random_state(seed) for seed in (3, 4)]
    y, ydot, applied = (jnp.stack(s) for s in zip(*states))
    yddot = jnp.stack([eo.accelerations(model, *s)[0] for s in states])
    # W Y'' + w - G against F: terms of up to ~2e2 N, rounding ~1e-13 N.
    np.testing.assert_allclose(
        eo.inverse_dynamics(model, y[0], ydot[0], yddot[0]), applied[0], atol=1e-10
    )
    np.testing.assert_allclose(
        eo.inverse_dynamics_series(model, y, ydot, yddot), applied, atol=1e-10
    )


@pytest.mark.slow  # over 10 s
@pytest.mark.parametrize("seed", [1, 2])
def test_constrained_solve_matches_a_dense_solve(seed):
    """Against an independent route: the full 6x6 blocks of `mass_matrix`, the
    autodiff forces, and `jnp.linalg.solve` with the prescribed rows replaced by
    unit rows; the reactions close W Y'' + w - G - F on the prescribed rows."""
    model = three_body_model()
    y, ydot, applied = _random_state(seed)
    mask = np.random.default_rng(seed).random((3, 6)) < 0.4
    a_p = jnp.asarray(np.random.default_rng(seed + 10).standard_normal((3, 6)))
    yddot, _, reaction = eo.constrained_accelerations(
        model, y, ydot, applied, mask, a_p
    )

    W = eo.mass_matrix(model, y)
    rhs = (
        model.gravity_forces()
        + applied
        - eo.velocity_terms(model, y, ydot)
        - eo.damping_forces(model, y, ydot)
        - eo.elastic_forces(model, y)
    )
    system = jnp.where(mask[:, :, None], jnp.eye(6), W)
    expected = jax.vmap(jnp.linalg.solve)(system, jnp.where(mask, a_p, rhs))
    np.testing.assert_allclose(yddot, expected, rtol=1e-10, atol=1e-10)
    residual = jnp.einsum("bij,bj->bi", W, yddot) - rhs
    np.testing.assert_allclose(reaction, jnp.where(mask, residual, 0.0), atol=1e-9)
    np.testing.assert_allclose(jnp.where(mask, 0.0, residual), 0.0, atol=1e-9)
