"""The closed-loop rest state: every coordinate free under a force law at rest.

Known truth: the residual is zero there, a simulation started there with the same
force law (no lift) stays there, and its derivative matches finite differences."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import three_body_model, three_body_state

import elasticoop as eo
from elasticoop._analysis import (
    closed_loop_residual,
    closed_loop_rest,
    closed_loop_stiffness,
)

HELD = np.zeros((3, 6), dtype=bool)
HELD[1:] = True
KP = (400.0, 400.0, 400.0, 5.0, 5.0, 5.0)
KD = (20.0, 20.0, 20.0, 0.1, 0.1, 0.1)


def _nominal(height=0.0):
    """The nominal system and a PoseTracking controller whose feedforward holds
    its grasps at rest (a scenario's feedforward = "hold"), frozen as numbers."""
    model = three_body_model()
    eq = eo.static_equilibrium(model, three_body_state(), HELD)
    y_eq = np.asarray(eq.y)
    control = eo.PoseTracking(
        y_ref=y_eq[1:],
        feedforward=np.asarray(eq.reaction)[1:],
        kp=KP,
        kd=KD,
        height=height,
        duration=1.0,
    )
    return model, y_eq, control


def _drawn(model, mass, scale=1.0):
    """`model` with the object's mass set and the grasps' stiffness scaled."""
    return eqx.tree_at(
        lambda m: (m.bodies.mass, m.stiffness),
        model,
        (model.bodies.mass.at[0].set(mass), model.stiffness * scale),
    )


@jax.jit
def _rest(mass, scale, model, y_guess, control):
    # one compilation for every test of this module
    return closed_loop_rest(_drawn(model, mass, scale), y_guess, control)


def test_the_nominal_system_rests_where_it_is_held():
    """With the feedforward of its own reactions, the nominal system's closed-loop
    rest is its held equilibrium: the controller adds nothing there."""
    model, y_eq, control = _nominal()
    y = _rest(2.0, 1.0, model, y_eq + 1e-3, control)
    np.testing.assert_allclose(y, y_eq, rtol=0, atol=1e-9)


def test_a_different_sample_rests_with_zero_residual_and_stays_at_rest():
    """A heavier, stiffer system under the same (frozen) commands: its grasps
    settle off the commanded poses, and a simulation from there stays there.
    Before, the start held the grasps at their poses: the frozen feedforward did
    not balance the sample's reactions, so it moved at once."""
    model, y_eq, control = _nominal()
    drawn = _drawn(model, 2.3, 1.2)
    y = np.asarray(_rest(2.3, 1.2, model, y_eq, control))
    residual = np.asarray(closed_loop_residual(drawn, y, control))
    assert np.abs(residual).max() < 1e-9
    # the grasps moved: a held start would not be at rest
    assert np.abs(y[1:] - y_eq[1:]).max() > 1e-4
    ts = np.linspace(0.0, 0.5, 6)
    traj = eo.simulate(
        drawn, y, np.zeros((3, 6)), ts, forces=control, rtol=1e-10, atol=1e-12
    )
    assert np.abs(np.asarray(traj.ydot)).max() < 1e-8
    np.testing.assert_allclose(traj.y, np.broadcast_to(y, traj.y.shape), atol=1e-9)
    # the old start (grasps held at their commanded poses) is not at rest
    held = eo.static_equilibrium(drawn, y_eq, HELD, np.asarray(control.feedforward))
    moved = eo.simulate(
        drawn, held.y, np.zeros((3, 6)), ts, forces=control, rtol=1e-10, atol=1e-12
    )
    assert np.abs(np.asarray(moved.ydot)).max() > 1e-3


def test_the_derivative_matches_finite_differences():
    """d Y*/d mass by the implicit function theorem (jacfwd through the jitted
    solve) against central differences of the solve."""
    model, y_eq, control = _nominal()
    mass, h = 2.3, 1e-5
    d = jax.jacfwd(_rest)(jnp.float64(mass), 1.2, model, y_eq, control)
    fd = (
        _rest(mass + h, 1.2, model, y_eq, control)
        - _rest(mass - h, 1.2, model, y_eq, control)
    ) / (2 * h)
    np.testing.assert_allclose(d, fd, rtol=1e-5, atol=1e-9)
    # the object sinks with its mass: the derivative is not trivially zero
    assert float(d[0, 2]) < -1e-3


def test_without_a_holding_force_law_the_stiffness_is_singular():
    """Constant forces leave the whole system free to drift: the closed-loop
    stiffness is singular, while PoseTracking's gains make it regular."""
    model, y_eq, control = _nominal()
    open_loop = closed_loop_stiffness(model, y_eq, None)
    assert np.linalg.matrix_rank(np.asarray(open_loop)) < 18
    closed = closed_loop_stiffness(model, y_eq, control)
    assert np.linalg.matrix_rank(np.asarray(closed)) == 18
    with pytest.raises(ValueError, match="nothing to solve for"):
        closed_loop_rest(model, y_eq, control, held=np.ones((3, 6), dtype=bool))
