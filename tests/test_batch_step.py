"""The batch loop's Runge-Kutta step against diffrax's: one step of each sample,
from its own time over its own step size, with the solver's tableau."""

import diffrax
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from elasticoop._integrate.rk_step import explicit_step, stage_buffer


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
