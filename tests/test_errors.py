"""Bad input raises a clear error naming the field; singularities are reported."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import run_tight, three_body_model, three_body_state

import elasticoop as eo

UP = (0.0, np.pi / 2, 0.0)
BODY = eo.RigidBody(1.0, (0.1, 0.2, 0.25))
CONN = dict(stiffness=[100.0] * 6, damping=[1.0] * 6)


def _K(n=2):
    """A valid stiffness: one x-spring between bodies 0 and 1."""
    k = np.zeros((6 * n, 6 * n))
    k[0, 0] = k[6, 6] = 10.0
    k[0, 6] = k[6, 0] = -10.0
    return k


BAD_INPUTS = {
    "negative mass": (lambda: eo.RigidBody(-1.0, (1, 1, 1)), "RigidBody.mass"),
    "zero inertia": (lambda: eo.RigidBody(1.0, (0, 1, 1)), "RigidBody.inertia"),
    "triangle inequality": (
        lambda: eo.RigidBody(1.0, (0.1, 0.1, 0.5)),
        "triangle inequality",
    ),
    "inertia shape": (lambda: eo.RigidBody(1.0, (1, 1)), r"RigidBody.inertia.*shape"),
    "nan mass": (
        lambda: eo.RigidBody(np.nan, (1, 1, 1)),
        "RigidBody.mass must be finite",
    ),
    "connection i == j": (lambda: eo.Connection(1, 1, **CONN), "different bodies"),
    "connection index negative": (lambda: eo.Connection(-1, 0, **CONN), "Connection.i"),
    "connection index out of range": (
        lambda: eo.MobileModel([BODY, BODY], [eo.Connection(0, 2, **CONN)]),
        "refers to body 2",
    ),
    "negative rest length": (
        lambda: eo.Connection(0, 1, **CONN, rest_length=-0.1),
        "rest_length must be >= 0",
    ),
    "negative stiffness": (
        lambda: eo.Connection(0, 1, stiffness=[-1.0] + [1.0] * 5, damping=[0.0] * 6),
        r"Connection\(0, 1\).stiffness",
    ),
    "complex stiffness": (
        lambda: eo.Connection(0, 1, stiffness=[1e3 + 1e3j] * 6, damping=[0.0] * 6),
        r"Connection\(0, 1\).stiffness must be real",
    ),
    "stiffness shape": (
        lambda: eo.Connection(0, 1, stiffness=[1.0] * 5, damping=[0.0] * 6),
        r"stiffness must have shape \(6,\), got shape \(5,\)",
    ),
    "inf damping": (
        lambda: eo.Connection(0, 1, stiffness=[1.0] * 6, damping=[np.inf] + [0.0] * 5),
        "damping must be finite",
    ),
    "unknown convention": (
        lambda: eo.MobileModel([BODY], convention="xyz"),
        "convention",
    ),
    "K wrong shape": (
        lambda: eo.ImmobileModel(
            [BODY, BODY], np.eye(6), np.zeros((12, 12)), np.zeros((2, 6))
        ),
        r"ImmobileModel.K must have shape \(12, 12\)",
    ),
    "K not symmetric": (
        lambda: eo.ImmobileModel(
            [BODY, BODY],
            _K() + np.triu(np.ones((12, 12)), 1),
            np.zeros((12, 12)),
            np.zeros((2, 6)),
        ),
        "K must be symmetric",
    ),
    "K indefinite": (
        lambda: eo.ImmobileModel(
            [BODY, BODY], -_K(), np.zeros((12, 12)), np.zeros((2, 6))
        ),
        "K must be positive semidefinite",
    ),
    "rank K > 6m": (
        lambda: eo.ImmobileModel(
            [BODY, BODY], np.eye(12), np.zeros((12, 12)), np.zeros((2, 6))
        ),
        r"rank K must be <= 6m = 6.*got rank K = 12",
    ),
    "D indefinite": (
        lambda: eo.ImmobileModel([BODY, BODY], _K(), -np.eye(12), np.zeros((2, 6))),
        "D must be positive semidefinite",
    ),
    "y0 nan": (
        lambda: eo.ImmobileModel(
            [BODY, BODY], _K(), np.zeros((12, 12)), np.full((2, 6), np.nan)
        ),
        "ImmobileModel.y0 must be finite",
    ),
    "negative gravity": (lambda: eo.MobileModel([BODY], gravity=-9.81), "gravity"),
    "not a body": (lambda: eo.MobileModel([BODY, "arm"]), r"bodies\[1\]"),
}


@pytest.mark.parametrize("case", list(BAD_INPUTS))
def test_bad_model_input_raises_clear_error(case):
    build, match = BAD_INPUTS[case]
    with pytest.raises(ValueError, match=match):
        build()


MODEL = three_body_model()
Y = three_body_state()
TS = jnp.linspace(0.0, 0.1, 5)
Z = jnp.zeros((3, 6))

BAD_SIMULATE = {
    "y_init shape": (dict(y_init=Y[:2]), r"y_init must have shape \(3, 6\)"),
    "y_init nan": (dict(y_init=Y.at[0, 0].set(jnp.nan)), "y_init must be finite"),
    "ydot_init inf": (
        dict(ydot_init=jnp.full((3, 6), jnp.inf)),
        "ydot_init must be finite",
    ),
    "ts decreasing": (dict(ts=TS[::-1]), "ts must be strictly increasing"),
    "ts repeated": (
        dict(ts=jnp.array([0.0, 0.1, 0.1])),
        "ts must be strictly increasing",
    ),
    "ts single": (dict(ts=jnp.array([0.0])), "at least 2 times"),
    "ts nan": (dict(ts=TS.at[2].set(jnp.nan)), "ts must be finite"),
    "force shape": (dict(forces=jnp.zeros((5, 6))), r"forces must give shape \(2, 6\)"),
    "force nan": (
        dict(forces=jnp.full((2, 6), jnp.nan)),
        "ConstantForce.F must be finite",
    ),
    "sampled force too short": (
        dict(forces=eo.SampledForce(jnp.array([0.0, 0.05]), jnp.zeros((2, 2, 6)))),
        r"SampledForce\) samples only cover",
    ),
    "start at gimbal lock": (
        dict(y_init=Y.at[1, 4].set(0.0)),
        r"y_init: body 1 starts at gimbal lock",
    ),
    "complex y_init": (dict(y_init=np.asarray(Y) + 1j), "y_init must be real"),
    "complex forces": (dict(forces=np.zeros((2, 6)) + 1j), "F must be real"),
    "rtol": (dict(rtol=-1.0), "rtol must be a positive number"),
    "rtol 1": (dict(rtol=1.0), r"simulate.rtol must be below 1 \(a relative error\)"),
    "gimbal_tol": (dict(gimbal_tol=2.0), r"simulate.gimbal_tol must be below 1"),
    "link_tol": (dict(link_tol=1.5), r"simulate.link_tol must be below 1"),
    "dt0 negative": (
        dict(dt0=-0.1),
        "simulate.dt0 must be a positive number, got -0.1",
    ),
    "dt0 zero": (dict(dt0=0.0), "simulate.dt0 must be a positive number, got 0.0"),
    "dt0 nan": (dict(dt0=float("nan")), "simulate.dt0 must be a positive number"),
    "model": (dict(model="beam"), "model must be an ImmobileModel or MobileModel"),
    "throw": (dict(throw="no"), r"simulate.throw must be True, False or None"),
}


@pytest.mark.parametrize("case", list(BAD_SIMULATE))
def test_bad_simulate_input_raises_clear_error(case):
    kwargs, match = BAD_SIMULATE[case]
    args = dict(model=MODEL, y_init=Y, ydot_init=jnp.zeros((3, 6)), ts=TS)
    args.update(kwargs)
    with pytest.raises(ValueError, match=match):
        eo.simulate(**args)


# A free body spinning about its body-x (= world-x) axis: theta(t) = theta0 + w t
# exactly, so the time the gimbal-lock threshold is reached is known in closed form.
THETA0, RATE = 0.5, -2.0
SPINNER = eo.MobileModel([BODY], gravity=0.0)


def _spin(rate):
    y0 = jnp.array([[0.0, 0.0, 0.0, 0.0, THETA0, 0.0]])
    ydot0 = jnp.array([[0.0, 0.0, 0.0, 0.0, rate, 0.0]])
    return y0, ydot0


def test_gimbal_lock_raises_with_body_and_time():
    y0, ydot0 = _spin(RATE)
    t_lock = (THETA0 - np.arcsin(eo.GIMBAL_TOL)) / abs(RATE)
    with pytest.raises(eo.SimulationError, match=r"gimbal lock: body 0") as info:
        run_tight(SPINNER, y0, ydot0, 1.0)
    traj = info.value.trajectory
    assert int(traj.status) == eo.Status.GIMBAL_LOCK
    np.testing.assert_allclose(float(traj.event_time), t_lock, rtol=1e-8)
    assert f"t = {float(traj.event_time):.9g} s" in str(info.value)
    assert "convention='rpy'" in str(info.value)
    # samples after the stop are NaN, before it finite
    assert np.all(np.isnan(np.asarray(traj.y)[np.asarray(traj.ts) > t_lock]))
    assert np.all(np.isfinite(np.asarray(traj.y)[np.asarray(traj.ts) < t_lock]))


@pytest.mark.slow  # compiles the batched run; test_transforms checks vmap fast
def test_gimbal_lock_in_a_batch_is_flagged_not_raised():
    rates = jnp.array([0.3, RATE, -0.2])

    def run(rate):
        y0, ydot0 = _spin(rate)
        return run_tight(SPINNER, y0, ydot0, 1.0)

    batch = jax.vmap(run)(rates)
    np.testing.assert_array_equal(batch.status, [0, eo.Status.GIMBAL_LOCK, 0])
    np.testing.assert_array_equal(batch.event_index, [-1, 0, -1])
    single = run(rates[0])
    np.testing.assert_allclose(batch.y[0], single.y, rtol=1e-13)
    # throw=True raises even when traced
    with pytest.raises(Exception, match="simulation stopped early"):
        jax.vmap(lambda r: run_tight(SPINNER, *_spin(r), 1.0, throw=True).y)(
            rates
        ).block_until_ready()


def test_collapsed_link_raises():
    """Two bodies rush together through a link of rest length rho: in 1-D the
    separation is x(t) = rho - (v/omega) sin(omega t) until the link collapses."""
    c, m, rho, v = 100.0, 1.0, 0.1, 2.0
    bodies = [eo.RigidBody(m, (0.1, 0.1, 0.1))] * 2
    link = eo.Connection(0, 1, stiffness=[c] * 6, damping=[0.0] * 6, rest_length=rho)
    model = eo.MobileModel(bodies, [link], gravity=0.0)
    y0 = jnp.array([[rho / 2, 0, 0, *UP], [-rho / 2, 0, 0, *UP]])
    ydot0 = jnp.zeros_like(y0).at[0, 0].set(-v / 2).at[1, 0].set(v / 2)
    with pytest.raises(
        eo.SimulationError, match=r"connection 0 between bodies 0 and 1"
    ):
        run_tight(model, y0, ydot0, 0.2)
    traj = run_tight(model, y0, ydot0, 0.2, throw=False)
    assert int(traj.status) == eo.Status.LINK_COLLAPSED
    omega = np.sqrt(c / (m / 2))
    t_hit = np.arcsin((1 - eo.LINK_TOL) * rho * omega / v) / omega
    np.testing.assert_allclose(float(traj.event_time), t_hit, rtol=1e-8)


def _link_pair(rho: float):
    """Two free bodies joined by one link of rest length `rho` along x."""
    bodies = [eo.RigidBody(1.0, (0.1, 0.1, 0.1))] * 2
    link = eo.Connection(
        0, 1, stiffness=[100.0] * 6, damping=[0.0] * 6, rest_length=rho
    )
    return eo.MobileModel(bodies, [link], gravity=0.0)


def _pair_state(separation):
    return jnp.array([[0.0, 0, 0, *UP], [0.0, 0, 0, *UP]]).at[1, 0].set(separation)


@pytest.mark.parametrize("fraction", [0.0, 0.5])
def test_link_collapsed_at_the_start_is_refused(fraction):
    """The collapse condition fires only when a link falls through its threshold:
    a start at or below it (here on top of each other, and at half the threshold)
    is refused, not simulated with a spring that has no direction."""
    rho = 0.1
    y0 = _pair_state(fraction * eo.LINK_TOL * rho)
    with pytest.raises(
        ValueError,
        match=r"y_init: connection 0 between bodies 0 and 1 starts collapsed",
    ):
        run_tight(_link_pair(rho), y0, jnp.zeros_like(y0), 0.1)


def test_link_collapsed_at_the_start_is_flagged_when_traced():
    """Traced, the start is not simulated: status LINK_COLLAPSED at ts[0] with the
    link's index, as a traced start at gimbal lock is flagged."""
    model = _link_pair(0.1)

    @jax.jit
    def run(separation):
        y0 = _pair_state(separation)
        traj = run_tight(model, y0, jnp.zeros_like(y0), 0.1, throw=False)
        return traj.status, traj.event_index, traj.event_time, traj.y

    status, index, t_event, y = run(0.0)
    assert int(status) == eo.Status.LINK_COLLAPSED
    assert int(index) == 0 and float(t_event) == 0.0
    assert np.all(np.isnan(np.asarray(y)))
    status, index, _, y = run(0.1)  # at rest length: nothing moves
    assert int(status) == eo.Status.SUCCESS and int(index) == -1
    np.testing.assert_allclose(y[-1], _pair_state(0.1), rtol=0, atol=1e-12)


def test_zero_rest_length_link_passes_through_zero_smoothly():
    c, m = 100.0, 1.0
    bodies = [eo.RigidBody(m, (0.1, 0.1, 0.1))] * 2
    link = eo.Connection(0, 1, stiffness=[c] * 6, damping=[0.0] * 6)
    model = eo.MobileModel(bodies, [link], gravity=0.0)
    y0 = jnp.array([[0.1, 0, 0, *UP], [-0.1, 0, 0, *UP]])
    traj = run_tight(model, y0, jnp.zeros_like(y0), 0.5)
    omega = np.sqrt(c / (m / 2))
    expected = 0.1 * np.cos(omega * np.asarray(traj.ts))
    np.testing.assert_allclose(traj.y[:, 0, 0], expected, atol=1e-9)


@pytest.mark.slow
def test_max_steps_is_reported():
    with pytest.raises(eo.SimulationError, match="max_steps"):
        eo.simulate(
            MODEL, Y.at[1, 0].add(-0.02), jnp.zeros((3, 6)), TS * 10, max_steps=3
        )


def test_traced_bad_value_raises_at_run_time():
    """Under jit the value checks go through eqx.error_if and still name the field."""
    with pytest.raises(Exception, match="RigidBody.mass must be positive"):
        jax.jit(lambda m: eo.RigidBody(m, (1.0, 1.0, 1.0)).mass)(
            -1.0
        ).block_until_ready()


BAD_DYNAMICS = {
    "applied of one row": (
        lambda: eo.accelerations(MODEL, Y, Z, jnp.ones(6)),
        r"accelerations.applied must have shape \(3, 6\), got shape \(6,\)",
    ),
    "flat state": (
        lambda: eo.elastic_forces(MODEL, np.zeros(18)),
        r"elastic_forces.y must have shape \(3, 6\), got shape \(18,\)",
    ),
    "rates not finite": (
        lambda: eo.velocity_terms(MODEL, Y, Z.at[0, 0].set(np.nan)),
        "velocity_terms.ydot must be finite",
    ),
    "text": (
        lambda: eo.damping_forces(MODEL, Y, "fast"),
        "damping_forces.ydot must be an array of numbers",
    ),
    # numbers written as text are text, as in a scenario file (before: read as
    # the numbers they spell)
    "a mass as text": (
        lambda: eo.RigidBody("2", (1e-3, 1e-3, 1e-3)),
        "RigidBody.mass must be an array of numbers, got '2'",
    ),
    "an inertia entry as text": (
        lambda: eo.RigidBody(2.0, ("1e-3", 1e-3, 1e-3)),
        r"RigidBody.inertia must be an array of numbers, got \('1e-3'",
    ),
    "stiffness of a flat state": (
        lambda: MODEL.stiffness_matrix(np.zeros((2, 6))),
        r"MobileModel.stiffness_matrix.y must have shape \(3, 6\), got shape \(2, 6\)",
    ),
    "gimbal lock": (
        lambda: eo.accelerations(MODEL, Y.at[2, 4].set(0.0), Z, Z),
        r"accelerations.y: body 2 starts at gimbal lock",
    ),
}


@pytest.mark.parametrize("case", list(BAD_DYNAMICS))
def test_bad_dynamics_input_raises_clear_error(case):
    call, match = BAD_DYNAMICS[case]
    with pytest.raises(ValueError, match=match):
        call()


def test_dynamics_terms_convert_to_float64():
    """Integer and float32 states are converted, not passed on: the terms are
    float64 and equal to those of the float64 state."""
    y = np.rint(np.asarray(Y) * 4) / 4  # exactly representable in both
    for state in (y.astype(np.float32), y.tolist()):
        W = eo.mass_matrix(MODEL, state)
        assert W.dtype == jnp.float64
        np.testing.assert_array_equal(W, eo.mass_matrix(MODEL, y))


def test_admissible_repeats_the_checks_of_construction():
    """`admissible` is false exactly where a constructor would refuse the values
    (for models changed by `eqx.tree_at`, which no constructor checks), traced
    or not."""
    import equinox as eqx

    assert bool(MODEL.admissible())
    inertia, stiffness = MODEL.bodies.inertia, MODEL.stiffness
    # what is changed, and what `simulate` says of it (the constructor's words)
    changes = {
        r"body 1: RigidBody.mass must be positive, got -0.3": (
            lambda m: m.bodies.mass,
            MODEL.bodies.mass.at[1].set(-0.3),
        ),
        r"body 0: RigidBody.inertia must be positive": (
            lambda m: m.bodies.inertia,
            inertia.at[0, 2].set(0.0),
        ),
        r"body 0: RigidBody.inertia violates the triangle inequality": (
            lambda m: m.bodies.inertia,
            inertia.at[0].set([0.01, 0.02, 0.04]),
        ),
        r"connection 1: Connection\(0, 2\).stiffness must be >= 0": (
            lambda m: m.stiffness,
            stiffness.at[1, 3].set(-1.0),
        ),
        r"connection 0: Connection\(0, 1\).damping must be >= 0": (
            lambda m: m.damping,
            MODEL.damping.at[0, 0].set(-1e-3),
        ),
        r"gravity must be finite and >= 0 \[m/s\^2\], got -9.81": (
            lambda m: m.gravity,
            jnp.asarray(-9.81),
        ),
    }
    admissible = jax.jit(lambda m: m.admissible())
    # traced leaves beside concrete ones
    angles = jnp.stack([MODEL.rest_angles, MODEL.rest_angles.at[0, 0].set(jnp.nan)])
    np.testing.assert_array_equal(
        jax.vmap(lambda a: eqx.tree_at(lambda m: m.rest_angles, MODEL, a).admissible())(
            angles
        ),
        [True, False],
    )
    for message, (where, value) in changes.items():
        changed = eqx.tree_at(where, MODEL, value)
        assert not bool(changed.admissible()), message
        assert not bool(admissible(changed)), message
        with pytest.raises(ValueError, match=f"constructor refuses: {message}"):
            eo.simulate(changed, Y, Z, TS)
    K = np.diag(np.r_[np.zeros(6), np.full(6, 100.0)])
    y0 = np.tile([0.0, 0, 0, *UP], (2, 1))
    immobile = eo.ImmobileModel([BODY] * 2, K, 0.1 * K, y0)
    assert bool(immobile.admissible())
    indefinite = K.copy()
    indefinite[6, 6] = -1.0
    coupled = K + np.eye(12, k=1)  # symmetric part couples a null direction
    for bad in (indefinite, coupled):
        changed = eqx.tree_at(lambda m: m.K, immobile, jnp.asarray(bad))
        assert not bool(changed.admissible())
        with pytest.raises(ValueError, match=r"refuses: K must be positive semidef"):
            eo.simulate(changed, y0, np.zeros((2, 6)), TS)
    # only the symmetric part enters the energy: a skew part is no instability
    skew = np.zeros((12, 12))
    skew[7, 8], skew[8, 7] = 5.0, -5.0
    changed = eqx.tree_at(lambda m: m.K, immobile, jnp.asarray(K + skew))
    assert bool(changed.admissible())


def _pose_tracking(**change):
    fields = dict(
        y_ref=np.asarray(Y)[1:],
        feedforward=np.zeros((2, 6)),
        kp=np.full(6, 100.0),
        kd=np.full(6, 1.0),
        height=0.1,
        duration=1.0,
    )
    return eo.PoseTracking(**(fields | change))


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(kp=np.full(3, 1e3)), r"PoseTracking.kp must have shape \(6,\)"),
        (
            dict(feedforward=np.zeros((3, 6))),
            r"y_ref and PoseTracking.feedforward must have one row per manipulator "
            r"each, got y_ref of shape \(2, 6\) and feedforward of shape \(3, 6\)",
        ),
        (  # the object's row given with the grasps' poses: both named
            dict(y_ref=np.asarray(Y)),
            r"got y_ref of shape \(3, 6\) and feedforward of shape \(2, 6\)",
        ),
        (
            dict(feedforward=np.zeros((2, 5))),
            r"PoseTracking.feedforward must have shape \(2, 6\)",
        ),
        (dict(y_ref=np.zeros(6)), r"PoseTracking.y_ref must have shape \(any, 6\)"),
        (dict(height=np.nan), "PoseTracking.height must be finite"),
        (dict(duration=0.0), r"PoseTracking.duration must be > 0 \[s\], got 0.0"),
        (dict(duration=-0.2), r"PoseTracking.duration must be > 0 \[s\], got -0.2"),
        (  # a negative gain drives the grasp away from its pose
            dict(kp=np.array([1e3, 1e3, -1e3, 10.0, 10.0, 10.0])),
            r"PoseTracking.kp must be >= 0 in every coordinate, got -1000.0 in "
            r"coordinate 2",
        ),
        (dict(kd=np.full(6, -1.0)), r"PoseTracking.kd must be >= 0 .* coordinate 0"),
    ],
)
def test_bad_pose_tracking_is_named(change, match):
    with pytest.raises(ValueError, match=match):
        _pose_tracking(**change)


def test_pose_tracking_is_still_built_under_jit():
    """Traced fields are checked for shape only: a force built inside `jit` (a
    batch of gains, say) is accepted."""
    force = jax.jit(lambda kp: _pose_tracking(kp=kp))(jnp.full(6, 50.0))
    np.testing.assert_array_equal(force.kp, 50.0)


def test_checks_of_concrete_values_stay_out_of_traces():
    """A traced model with a constant state (`jit`, `vmap` or `grad` over model
    parameters) and a constant state under `jit` are simulated and evaluated, not
    inspected in Python (that raised a tracer conversion error)."""
    y0 = np.asarray(Y)
    status = jax.jit(lambda m: eo.simulate(m, y0, Z, TS, throw=False).status)(MODEL)
    assert int(status) == eo.Status.SUCCESS
    yddot = jax.jit(lambda: eo.accelerations(MODEL, y0, Z, Z)[0])()
    np.testing.assert_allclose(yddot, eo.accelerations(MODEL, y0, Z, Z)[0], rtol=1e-14)


def test_admissible_sees_values_that_are_not_finite():
    import equinox as eqx

    for where, value in (
        (lambda m: m.bodies.mass, MODEL.bodies.mass.at[0].set(np.inf)),
        (lambda m: m.stiffness, MODEL.stiffness.at[0, 0].set(np.inf)),
        (lambda m: m.rest_angles, MODEL.rest_angles.at[0, 0].set(np.nan)),
    ):
        assert not bool(eqx.tree_at(where, MODEL, value).admissible())
    K = np.diag(np.r_[np.zeros(6), np.full(6, 100.0)])
    y0 = np.tile([0.0, 0, 0, *UP], (2, 1))
    immobile = eo.ImmobileModel([BODY] * 2, K, 0.1 * K, y0)
    broken = eqx.tree_at(lambda m: m.K, immobile, immobile.K.at[6, 6].set(np.nan))
    assert not bool(broken.admissible())  # (NumPy's eigenvalues fail on NaN)
    assert not bool(jax.jit(lambda m: m.admissible())(broken))
    assert bool(jax.jit(lambda m: m.admissible())(immobile))
    with pytest.raises(ValueError, match=r"refuses: ImmobileModel.K must be finite"):
        eo.simulate(broken, y0, np.zeros((2, 6)), TS)
    # a force's own range: a lift of no duration
    from elasticoop._forces import force_admissible

    lift = _pose_tracking()
    assert bool(force_admissible(lift))
    stopped = eqx.tree_at(lambda f: f.duration, lift, jnp.asarray(0.0))
    assert not bool(force_admissible(stopped))
    assert not bool(jax.jit(force_admissible)(stopped))
    # and gains >= 0 (a Monte Carlo draw of a gain below zero is no controller)
    pushing = eqx.tree_at(lambda f: f.kp, lift, lift.kp.at[4].set(-1.0))
    assert not bool(force_admissible(pushing))
    assert not bool(jax.jit(force_admissible)(pushing))


@pytest.mark.parametrize("n_output", [0, 1, 2.5, True])
def test_default_scenario_needs_two_or_more_output_samples(n_output):
    with pytest.raises(ValueError, match=r"n_output must be"):
        eo.default_scenario(n_output)


@pytest.mark.parametrize(
    "change, match",
    [
        (dict(y_init=np.zeros((2, 6))), r"Scenario.y_init must have shape \(3, 6\)"),
        (dict(ydot_init=np.full((3, 6), np.nan)), r"Scenario.ydot_init must be finite"),
        (dict(ts=[0.0]), r"Scenario.ts needs at least 2 times, got 1"),
        (dict(ts=[0.0, 0.2, 0.1]), r"Scenario.ts must be strictly increasing"),
        (dict(model="beam"), r"Scenario.model must be an ImmobileModel or a Mob"),
    ],
)
def test_a_scenario_is_checked_when_it_is_built(change, match):
    """A wrong shape or time grid is named where the scenario is made, not at its
    first run."""
    fields = dict(name="x", model=MODEL, y_init=Y, ydot_init=Z, ts=TS, forces=None)
    with pytest.raises(ValueError, match=match):
        eo.Scenario(**(fields | change))


def test_a_mask_in_the_place_of_forces_is_refused():
    """`rest_state(model, y, held)` puts the mask where the forces go (they come
    third, as in `simulate`): its booleans were read as forces of 1 N."""
    held = np.zeros((3, 6), bool)
    held[1:] = True
    with pytest.raises(ValueError, match=r"rest_state.forces must be an array of num"):
        eo.rest_state(MODEL, Y, held)
    with pytest.raises(ValueError, match=r"F must be an array of numbers, got an arr"):
        eo.simulate(MODEL, Y, Z, TS, forces=held[1:])
    # and NaN, which sent the solver off to fail to converge (or, in the forces on
    # the grasps, was returned as a finite rest state)
    guess = np.asarray(Y).copy()
    guess[0, 2] = np.nan
    with pytest.raises(ValueError, match=r"rest_state.y_guess must be finite"):
        eo.rest_state(MODEL, guess)
    with pytest.raises(ValueError, match=r"rest_state.forces must be finite"):
        eo.rest_state(MODEL, Y, np.full((2, 6), np.nan))
