"""Locating the crossing of a stop condition inside the last step."""

import jax.numpy as jnp
import numpy as np

from elasticoop._integrate.events import hermite, locate_event

T0, T1 = 0.2, 0.7
STEP = (jnp.asarray(T0), jnp.asarray(T1))
COEFFS = np.array([[0.3, -1.2, 0.5, 2.0], [-0.4, 0.1, 1.5, -0.7]])  # cubics in t
SCALE = np.arange(1.0, 7.0)  # a state of shape (2 bodies, 6): scaled copies


def _path(t):
    """Cubic polynomials of t, shape (2, 6), and their derivatives."""
    y = np.array([np.polyval(c, t) for c in COEFFS])
    ydot = np.array([np.polyval(np.polyder(c), t) for c in COEFFS])
    return jnp.asarray(np.outer(y, SCALE)), jnp.asarray(np.outer(ydot, SCALE))


def test_hermite_reproduces_cubics_and_their_rates():
    start, end = _path(T0), _path(T1)
    for t in np.linspace(T0, T1, 7):
        y, ydot = hermite(jnp.asarray(t), *STEP, *start, *end)
        exact_y, exact_ydot = _path(t)
        np.testing.assert_allclose(y, exact_y, rtol=1e-13, atol=1e-14)
        np.testing.assert_allclose(ydot, exact_ydot, rtol=1e-12, atol=1e-13)


def test_the_triggered_condition_decides_the_crossing():
    start, end = _path(T0), _path(T1)
    level = float(np.polyval(COEFFS[0], 0.55))  # crossed once in the step

    def first(t, y, args):
        return y[0, 0] - args

    def never(t, y, args):
        return jnp.asarray(np.inf)

    def locate(*triggered):
        mask = [jnp.array(x) for x in triggered]
        return locate_event(*STEP, start, end, level, [never, first], mask)

    t, y, _ = locate(False, True)
    np.testing.assert_allclose(float(t), 0.55, rtol=1e-12)
    np.testing.assert_allclose(y, _path(0.55)[0], rtol=1e-12)
    # nothing triggered: the step's end
    t, y, _ = locate(False, False)
    assert float(t) == T1
    np.testing.assert_allclose(y, end[0], rtol=1e-13)
