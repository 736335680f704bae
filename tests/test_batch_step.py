"""The batch loop's Runge-Kutta step against diffrax's: one step of each sample,
from its own time over its own step size, with the solver's tableau."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from elasticoop._integrate.rk_step import dense_weights, explicit_step, stage_buffer


def _field(t, y, args=None):
    """A nonlinear, time-dependent vector field of one state (or, with `t` of
    shape `(batch,)`, of a batch of states)."""
    t = jnp.reshape(t, jnp.shape(t) + (1,) * (y.ndim - jnp.ndim(t)))
    return 10.0 * jnp.sin(1.3 * y + t) * jnp.cos(y[..., ::-1])


@pytest.mark.parametrize(
    "solver",
    [diffrax.Tsit5(), diffrax.Dopri5(), diffrax.Dopri8(), diffrax.Bosh3(),
     diffrax.Heun(), diffrax.Ralston()],
    ids=["tsit5", "dopri5", "dopri8", "bosh3", "heun", "ralston"],
)  # fmt: skip
def test_a_step_equals_diffrax_to_rounding(solver):
    batch = 16
    y0 = jax.random.normal(jax.random.key(0), (batch, 7))
    t0 = jnp.linspace(0.0, 1.0, batch)
    t1 = t0 + jnp.linspace(1e-3, 3e-2, batch)
    tableau = solver.tableau
    f0 = _field(t0, y0) if tableau.fsal else None

    def diffrax_step(t0, t1, y0):
        state = solver.init(diffrax.ODETerm(_field), t0, t1, y0, None)
        y1, y_error, dense, state, _ = solver.step(
            diffrax.ODETerm(_field), t0, t1, y0, None, state, False
        )
        f_last = state[1] if tableau.fsal else y1
        return y1, y_error, dense["k"], f_last

    y1, y_error, k, f_last = jax.jit(jax.vmap(diffrax_step))(t0, t1, y0)
    want = (y1, y_error, jnp.moveaxis(k, 0, 1), f_last)  # k: (stages, batch, 7)
    # a buffer left with NaN by an earlier step: it must not leak into this one
    stale = stage_buffer(tableau, y0) + jnp.nan
    got = jax.jit(lambda *a: explicit_step(tableau, _field, *a))(t0, t1, y0, f0, stale)
    # the same formulas; diffrax's sums fuse each product (FMA), these round it:
    # a few units in the last place of the states, to which the stages' inputs
    # are rounded (the increments, the error estimate and y1 all follow them)
    atol = 4 * np.finfo(float).eps * float(jnp.max(jnp.abs(y0)))
    for name, a, b in zip(("y1", "y_error", "k"), got[:3], want[:3], strict=True):
        np.testing.assert_allclose(a, b, rtol=0, atol=atol, err_msg=name)
    if tableau.fsal:
        np.testing.assert_allclose(got.f_last, want[3], rtol=1e-13, atol=1e-13)


def test_an_implicit_tableau_is_refused():
    with pytest.raises(ValueError, match="explicit"):
        explicit_step(
            diffrax.Kvaerno3().tableau, _field, jnp.zeros(2), jnp.ones(2),
            jnp.zeros((2, 3)), None, jnp.zeros((4, 2, 3)),
        )  # fmt: skip


@pytest.mark.parametrize(
    "solver",
    [diffrax.Tsit5(), diffrax.Dopri8(), diffrax.Heun()],
    ids=["tsit5", "dopri8", "heun"],
)
def test_the_replay_step_keeps_the_stage_inputs(solver):
    """The adjoint's replay: the stages' inputs $y_i = y_0 + \\sum_j a_{ij} k_j$
    kept, the last stage left out where $y_1$ does not use it, $y_1$ unchanged."""
    batch = 4
    y0 = jax.random.normal(jax.random.key(1), (batch, 5))
    t0 = jnp.linspace(0.0, 1.0, batch)
    t1 = t0 + 0.02
    tableau = solver.tableau
    buffer = stage_buffer(tableau, y0)
    full = explicit_step(tableau, _field, t0, t1, y0, None, buffer)
    last = bool(tableau.b_sol[-1] != 0)
    replay = explicit_step(
        tableau, _field, t0, t1, y0, None, buffer, stage_inputs=True,
        evaluate_last=last,
    )  # fmt: skip
    # (the last input formed outside the stages' loop: rounded alike, not bitwise)
    atol = 4 * np.finfo(float).eps * float(jnp.max(jnp.abs(y0)))
    np.testing.assert_allclose(replay.y1, full.y1, rtol=0, atol=atol)
    assert (replay.y_error is None) == (not last)
    rows = [np.zeros(1), *tableau.a_lower]
    for i, row in enumerate(rows):
        want = y0 + sum(a * full.ks[j] for j, a in enumerate(row))
        np.testing.assert_allclose(replay.inputs[i], want, rtol=0, atol=atol)


def test_the_dense_weights_give_diffrax_dense_output():
    solver = diffrax.Dopri8()
    y0 = jax.random.normal(jax.random.key(2), (3,))
    term = diffrax.ODETerm(_field)
    state = solver.init(term, 0.2, 0.25, y0, None)
    y1, _, dense, _, _ = solver.step(term, 0.2, 0.25, y0, None, state, False)
    for t in (0.2, 0.213, 0.25):
        w = dense_weights(solver, 0.2, 0.25, t)
        got = w[0] * y0 + w[1] * y1 + jnp.tensordot(w[2:], dense["k"], 1)
        want = solver.interpolation_cls(t0=0.2, t1=0.25, **dense).evaluate(t)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
