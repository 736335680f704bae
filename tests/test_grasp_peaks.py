"""Peak grasp loads (elastic + damping, between the saved samples) and the applied
forces exported with a trajectory."""

import types

import jax.numpy as jnp
import numpy as np

import elasticoop as eo
from elasticoop._io.grasp_peaks import hermite, peak_grasp_loads
from elasticoop._io.xarray import applied_forces


def test_hermite_interpolant_is_exact_for_a_cubic():
    ts = np.array([0.0, 0.3, 1.0])
    y, ydot = ts**3 - 2 * ts, 3 * ts**2 - 2
    yy, vv = hermite(ts, y[:, None], ydot[:, None], refine=4)
    fine = np.concatenate([np.linspace(0, 0.3, 5)[:-1], np.linspace(0.3, 1.0, 5)])
    np.testing.assert_allclose(yy[:, 0], fine**3 - 2 * fine, atol=1e-14)
    np.testing.assert_allclose(vv[:, 0], 3 * fine**2 - 2, atol=1e-13)


def test_peak_grasp_force_has_the_damping_and_falls_between_samples():
    # one link along x whose length oscillates, L = rho0 + a sin(w t): its force
    # c (L - rho0) + b L' peaks at a sqrt(c^2 + b^2 w^2), between the samples
    c, b, rho0, a, w = 1000.0, 20.0, 0.5, 0.01, 30.0
    body = eo.RigidBody(1.0, (0.01, 0.01, 0.01))
    link = eo.Connection(0, 1, (c,) * 3 + (1.0,) * 3, (b,) * 3 + (0.1,) * 3, rho0)
    model = eo.MobileModel([body, body], [link], convention="rpy")
    # six samples per period, the nearest a sixth of a period from each peak
    peak_phase = np.arctan2(c, b * w)
    ts = (peak_phase + np.pi / 6 + np.arange(12) * np.pi / 3) / w
    y, ydot = np.zeros((12, 2, 6)), np.zeros((12, 2, 6))
    y[:, 1, 0] = rho0 + a * np.sin(w * ts)
    ydot[:, 1, 0] = a * w * np.cos(w * ts)
    traj = types.SimpleNamespace(model=model, ts=ts, y=y, ydot=ydot)
    force, torque = peak_grasp_loads(traj)
    exact = a * np.hypot(c, b * w)
    np.testing.assert_allclose(force, [exact], rtol=0.01)
    np.testing.assert_allclose(torque, [0.0], atol=1e-12)
    at_samples, _ = peak_grasp_loads(traj, refine=1)
    np.testing.assert_allclose(at_samples, [np.cos(np.pi / 6) * exact])  # missed
    # the elastic force alone never exceeds c a: the peak includes the damping
    assert force[0] > 1.1 * c * a


def test_applied_forces_at_the_saved_samples():
    ts = jnp.array([0.0, 0.5])
    y = jnp.arange(36.0).reshape(2, 3, 6) / 100
    ydot = jnp.ones((2, 3, 6))
    traj = types.SimpleNamespace(
        model=types.SimpleNamespace(n_bodies=3), ts=ts, y=y, ydot=ydot
    )
    rows = np.arange(12.0).reshape(2, 6)
    out = applied_forces(eo.ConstantForce(rows), traj)
    assert out.shape == (2, 3, 6)
    np.testing.assert_array_equal(out[:, 0], 0.0)  # no force on the object
    np.testing.assert_array_equal(out[:, 1:], np.broadcast_to(rows, (2, 2, 6)))
    # PD tracking at t = 0 (no lift yet): F = ff + kp (ref - y) - kd ydot
    kp, kd = np.full(6, 10.0), np.full(6, 2.0)
    ref, ff = np.zeros((2, 6)), np.ones((2, 6))
    pd = eo.PoseTracking(
        jnp.asarray(ref),
        jnp.asarray(ff),
        jnp.asarray(kp),
        jnp.asarray(kd),
        jnp.asarray(0.1),
        jnp.asarray(1.0),
    )
    out = applied_forces(pd, traj)
    np.testing.assert_allclose(out[0, 1:], ff - kp * np.asarray(y[0, 1:]) - kd)


def test_early_stop_message_names_the_bodies_and_connection():
    from elasticoop._status import Status, status_message

    body = eo.RigidBody(1.0, (0.01, 0.01, 0.01))
    link = eo.Connection(0, 1, (1.0,) * 6, (0.0,) * 6, 0.5)
    model = eo.MobileModel([body, body], [link], convention="rpy")
    traj = types.SimpleNamespace(
        model=model, status=Status.LINK_COLLAPSED, event_time=0.25, event_index=0
    )
    named = status_message(traj, ("plate", "hand"), ("grip",))
    assert "connection 'grip' between bodies 'plate' and 'hand'" in named
    assert "between bodies 0 and 1" in status_message(traj)
    traj.status, traj.event_index = Status.NONFINITE, 1
    assert "forces of body 'hand'" in status_message(traj, ("plate", "hand"))
