"""Load distribution: squeezing, the grasp-matrix identities, and the statics of a
held object (reactions converted to physical wrenches)."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import UPRIGHT, hold, run_tight

import elasticoop as eo

POINTS = np.array([[-0.5, 0.0, 1.0], [0.5, 0.0, 1.0]])
CENTER = np.array([0.0, 0.0, 1.0])


def numpy_grasp_matrix(points, center):
    blocks = []
    for p in points:
        r = p - center
        skew = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
        blocks.append(np.block([[np.eye(3), np.zeros((3, 3))], [skew, np.eye(3)]]))
    return np.concatenate(blocks, axis=1)


def test_equal_and_opposite_squeeze_is_all_internal():
    squeeze = np.array([[30.0, 0, 0, 0, 0, 0], [-30.0, 0, 0, 0, 0, 0]])
    ld = eo.load_distribution(squeeze, POINTS, CENTER)
    np.testing.assert_allclose(ld.internal, squeeze, atol=1e-12)
    np.testing.assert_allclose(ld.motion, 0.0, atol=1e-12)
    np.testing.assert_allclose(ld.object_wrench, 0.0, atol=1e-12)
    assert float(ld.internal_share()) == pytest.approx(1.0)


def test_shared_lift_is_all_motion():
    lift = np.array([[0.0, 0, 10.0, 0, 0, 0], [0.0, 0, 10.0, 0, 0, 0]])
    ld = eo.load_distribution(lift, POINTS, CENTER)
    np.testing.assert_allclose(ld.motion, lift, atol=1e-12)
    np.testing.assert_allclose(ld.internal, 0.0, atol=1e-12)
    np.testing.assert_allclose(ld.object_wrench, [0, 0, 20.0, 0, 0, 0], atol=1e-12)


def test_split_identities_for_random_wrenches():
    rng = np.random.default_rng(3)
    points = rng.normal(size=(5, 4, 3))
    center = rng.normal(size=(5, 3))
    wrenches = rng.normal(size=(5, 4, 6))
    ld = eo.load_distribution(wrenches, points, center, length=0.7)
    for b in range(5):
        G = numpy_grasp_matrix(points[b], center[b])
        np.testing.assert_allclose(
            ld.object_wrench[b], G @ wrenches[b].reshape(-1), atol=1e-12
        )
        np.testing.assert_allclose(G @ np.ravel(ld.internal[b]), 0.0, atol=1e-12)
        np.testing.assert_allclose(G @ np.ravel(ld.motion[b]), ld.object_wrench[b])
        # the motion part is orthogonal (in the weighted norm) to the null space
        S = np.tile([1, 1, 1, 0.7, 0.7, 0.7], 4)
        inner = np.ravel(ld.motion[b]) / S**2 @ np.ravel(ld.internal[b])
        assert abs(inner) < 1e-10
    np.testing.assert_allclose(ld.motion + ld.internal, wrenches, atol=1e-12)


@pytest.mark.slow
def test_held_object_statics():
    """Grasps held still at a static equilibrium: the grasp wrenches carry the
    weight of everything and balance the moment of the grasps' own weight.

    The appendix's springs are not rotation invariant (docs/model.md, section 3.4):
    a link force C delta with unequal cx, cy, cz is not along the link, and the
    Euler-angle springs' equal and opposite generalized torques are equal and
    opposite physical torques only between equally oriented bodies. The assembly's
    exact moment balance therefore needs isotropic link stiffness and one
    orientation."""
    up = UPRIGHT["zxz"]
    y = jnp.array(
        [
            [0.0, 0.0, 1.0, *up],
            [-0.5, 0.0, 1.05, *up],
            [0.45, 0.1, 1.0, *up],
        ]
    )
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    k = (900.0, 900.0, 900.0, 20.0, 25.0, 30.0)
    conns = [eo.Connection(0, i, k, (5.0,) * 3 + (0.05,) * 3) for i in (1, 2)]
    model = eo.MobileModel(bodies, conns).with_unloaded_state(y)
    grasps = np.zeros((3, 6), bool)
    grasps[1:] = True
    eq = eo.static_equilibrium(model, y, grasps)
    held = hold(grasps, eq.y)
    traj = run_tight(model, eq.y, jnp.zeros_like(eq.y), 0.1, prescribed=held)
    ld = eo.trajectory_load_distribution(traj)
    masses = np.array([2.0, 0.3, 0.25])
    g = 9.81
    expected_torque = sum(
        np.cross(
            np.asarray(eq.y[i, :3]) - np.asarray(eq.y[0, :3]), [0, 0, masses[i] * g]
        )
        for i in (1, 2)
    )
    expected = np.concatenate([[0.0, 0.0, g * masses.sum()], expected_torque])
    np.testing.assert_allclose(ld.object_wrench[-1], expected, atol=1e-8)
    np.testing.assert_allclose(
        ld.motion[-1] + ld.internal[-1], eo.grasp_wrenches(traj)[-1], atol=1e-12
    )


def test_bad_load_inputs():
    with pytest.raises(ValueError, match="points must have shape"):
        eo.load_distribution(np.zeros((2, 6)), np.zeros((3, 3)), CENTER)
    with pytest.raises(ValueError, match="center must have shape"):
        eo.load_distribution(np.zeros((2, 6)), POINTS, np.zeros(2))
    with pytest.raises(ValueError, match="length must be a positive"):
        eo.load_distribution(np.zeros((2, 6)), POINTS, CENTER, length=-1.0)
    with pytest.raises(ValueError, match="wrenches must be finite"):
        eo.load_distribution(np.full((2, 6), np.nan), POINTS, CENTER)
