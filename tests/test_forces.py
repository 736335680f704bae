"""Force inputs and the wrench -> generalized force map."""

import jax.numpy as jnp
import numpy as np
import pytest

import elasticoop as eo


@pytest.mark.parametrize("convention", ["zxz", "rpy"])
@pytest.mark.parametrize("frame", ["world", "body"])
def test_generalized_wrench_preserves_virtual_power(convention, frame):
    """Q . Ydot = f . v + tau . omega for every velocity (virtual work)."""
    rot = eo.get_rotation(convention)
    rng = np.random.default_rng(3)
    angles = jnp.array([0.4, 1.1, -0.7])
    force, torque = rng.normal(size=3), rng.normal(size=3)
    Q = eo.generalized_wrench(angles, force, torque, frame=frame, convention=convention)
    R = rot.matrix(angles)
    for _ in range(3):
        ydot = jnp.array(rng.normal(size=6))
        omega_body = rot.angular_velocity(angles, ydot[3:])
        if frame == "world":
            power = force @ ydot[:3] + torque @ (R @ omega_body)
        else:
            power = (R @ force) @ ydot[:3] + torque @ omega_body
        np.testing.assert_allclose(Q @ ydot, power, rtol=1e-13)


def test_sampled_force_interpolates_linearly():
    ts = jnp.array([0.0, 0.5, 1.0, 2.0])
    F = jnp.array(np.random.default_rng(0).normal(size=(4, 2, 6)))
    force = eo.SampledForce(ts, F)
    for t in (0.0, 0.25, 0.7, 1.5, 2.0):
        expected = np.stack(
            [[np.interp(t, ts, F[:, i, k]) for k in range(6)] for i in range(2)]
        )
        np.testing.assert_allclose(force(t, None, None), expected, rtol=1e-14)
    np.testing.assert_array_equal(force.jump_ts, ts)


def test_bad_force_inputs():
    with pytest.raises(ValueError, match="SampledForce.ts must be strictly increasing"):
        eo.SampledForce(jnp.array([0.0, 1.0, 0.5]), jnp.zeros((3, 2, 6)))
    with pytest.raises(
        ValueError, match=r"SampledForce.F must have shape \(2, any, 6\)"
    ):
        eo.SampledForce(jnp.array([0.0, 1.0]), jnp.zeros((3, 2, 6)))
    with pytest.raises(ValueError, match="frame must be"):
        eo.generalized_wrench(jnp.zeros(3), jnp.zeros(3), jnp.zeros(3), frame="tool")
