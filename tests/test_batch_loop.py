"""`simulate(..., batch_loop=True)` under `vmap` integrates the batch in one loop, each
element with its own steps. Checked against `vmap` of diffrax's own loop (the
default, which equals single runs to rounding): the same number of steps, statuses
and events, and the same states and event times to the solver's tolerance, in
batches where elements stop early (NaN inputs, max_steps, gimbal lock, a collapsed
link, the end of sampled forces), take jump times, follow prescribed motion or use
other solvers.

Why to the tolerance and not to rounding: the batch loop's step sums the stages
elementwise, diffrax's with dot products that fuse each product into its sum, so a
step differs by rounding (`tests/test_batch_step.py` compares single steps to a few
units in the last place). The step-size controller turns that into steps that
differ by rounding too, and a run into states that differ by more than one step's
rounding: up to about 5e-12 in these runs, within their tolerance (rtol 1e-8, atol
1e-10 here)."""

import functools

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SMALL_TS, TIGHT, hold, run_tight, small_two_body_model

import elasticoop as eo

MODEL, Y0 = small_two_body_model()
YDOT0 = jnp.zeros_like(Y0).at[1, 2].set(0.5)
LIFT = jnp.array([[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]])
UP = (0.0, np.pi / 2, 0.0)
# The two-body runs' solver and tolerances: Tsit5 at rtol 1e-8, on which the
# step counts of the batch below (and its `max_steps` between them) were chosen.
SOLVER = "tsit5"
TOLERANCES = dict(rtol=1e-8, atol=1e-10)


def _both(run, *batched):
    """`run` vmapped over `batched`, with diffrax's loop and with the batch loop."""
    plain = jax.vmap(lambda *a: run(*a, batch_loop=False))(*batched)
    loop = jax.vmap(lambda *a: run(*a, batch_loop=True))(*batched)
    return plain, loop


def _assert_same(plain: eo.Trajectory, loop: eo.Trajectory, rtol=1e-8, atol=1e-10):
    """The same steps, statuses and events; the same states, energies, reactions
    and event times to the run's tolerance (`rtol`, `atol`: `TOLERANCES`)."""
    for name in ("status", "event_index", "n_steps"):
        np.testing.assert_array_equal(
            getattr(loop, name), getattr(plain, name), err_msg=name
        )
    for name in ("y", "ydot", "work", "dissipated", "reaction"):
        if getattr(plain, name) is None:
            assert getattr(loop, name) is None
            continue
        np.testing.assert_allclose(
            getattr(loop, name), getattr(plain, name), rtol=rtol, atol=atol,
            err_msg=name,
        )  # fmt: skip
    # an element stopped by max_steps stopped where its steps took it: the sum of
    # step sizes that the controller set from error estimates (differences of the
    # stages, whose rounding is large relative to them), compounded over every
    # step; it must stop within a thousandth of a mean step of diffrax's
    limited = np.asarray(plain.status == eo.Status.MAX_STEPS_REACHED)
    t_loop, t_plain = np.asarray(loop.event_time), np.asarray(plain.event_time)
    np.testing.assert_allclose(
        t_loop[~limited], t_plain[~limited], rtol=rtol, atol=atol, err_msg="event_time"
    )
    span = t_plain - np.asarray(plain.ts)[:, 0]
    mean_step = span[limited] / np.asarray(plain.n_steps)[limited]
    assert np.all(np.abs(t_loop[limited] - t_plain[limited]) < 1e-3 * mean_step)


def _two_body(stiffness, force, y_init, max_steps=200, **options):
    model = eqx.tree_at(lambda m: m.stiffness, MODEL, stiffness)
    return eo.simulate(
        model,
        y_init,
        YDOT0,
        SMALL_TS,
        forces=force,
        options=eo.SimulationOptions(SOLVER, **TOLERANCES, max_steps=max_steps),
        throw=False,
        **options,
    )


@functools.lru_cache(typed=True)  # (True and 1 apart)
def _failing_batch(batch_loop):
    """`_two_body` vmapped over a batch with failing elements, with `batch_loop`
    (False: diffrax's loop); each run once for the tests that check it. Stiff and
    soft grasps (different steps), a NaN force, a NaN start, and max_steps between
    the step counts of the soft and the stiff grasps; twice over, so that in a few
    lanes elements wait for a free one."""
    scale = jnp.array([1.0, 30.0, 1.0, 1.0, 0.5] * 2)[:, None, None]
    forces = jnp.stack([LIFT, LIFT, LIFT.at[0, 2].set(jnp.nan), LIFT, 0.5 * LIFT] * 2)
    starts = jnp.stack([Y0, Y0, Y0, Y0.at[1, 4].set(jnp.nan), Y0] * 2)
    run = lambda *a: _two_body(*a, batch_loop=batch_loop)  # noqa: E731
    return jax.vmap(run)(scale * MODEL.stiffness[None], forces, starts)


# the statuses of the failing batch
NONFINITE, MOST = eo.Status.NONFINITE, eo.Status.MAX_STEPS_REACHED
FAILING_STATUS = [0, MOST, NONFINITE, NONFINITE, 0] * 2


@pytest.mark.slow
def test_batch_equals_vmap_of_single_runs_with_failing_elements():
    plain, loop = _failing_batch(False), _failing_batch(True)
    np.testing.assert_array_equal(plain.status, FAILING_STATUS)
    _assert_same(plain, loop)
    # elements do not wait for each other: the soft ones stop at their own steps
    assert int(loop.n_steps[0]) < int(loop.n_steps[1]) == 200


@pytest.mark.slow  # over 10 s
def test_a_few_lanes_at_a_time_equal_the_whole_batch_at_once():
    # batch_loop=n: n elements at once, each next one starting as one stops; the
    # batch of the test above (failures, max_steps) in 2 and 3 lanes
    whole, two = _failing_batch(True), _failing_batch(2)
    three, wide = _failing_batch(3), _failing_batch(16)
    np.testing.assert_array_equal(two.status, FAILING_STATUS)
    _assert_same(whole, two, **TIGHT)
    # how many lanes, and which lane an element ran in, changes nothing (16: more
    # lanes than elements, none waiting, every result stored after the loop)
    for other in (three, wide):
        for a, b in zip(jax.tree.leaves(two), jax.tree.leaves(other), strict=True):
            np.testing.assert_array_equal(a, b)


@pytest.mark.parametrize("lanes", [0, -2])
def test_batch_loop_takes_a_bool_or_a_positive_integer(lanes):
    with pytest.raises(ValueError, match="batch_loop must be"):
        _two_body(MODEL.stiffness, LIFT, Y0, batch_loop=lanes)


@pytest.mark.slow
def test_outside_vmap_it_is_the_plain_run_differentiable_with_the_default_adjoint():
    def final_height(stiffness, batch_loop, **options):
        traj = _two_body(
            MODEL.stiffness * stiffness, LIFT, Y0, batch_loop=batch_loop, **options
        )
        return traj.y[-1, 1, 2]

    assert float(final_height(1.0, True)) == float(final_height(1.0, False))
    # the default adjoint (stepwise) differentiates the batch loop's solve: the
    # same gradient program as the plain run's (so the same gradient bitwise)
    gradient = jax.jit(jax.grad(final_height), static_argnums=1)
    program = gradient.lower(1.0, True).as_text()
    assert program == gradient.lower(1.0, False).as_text()
    assert np.isfinite(float(gradient(1.0, True)))
    # with a diffrax adjoint the batch loop is for forward runs only
    with pytest.raises(ValueError, match=r"with a diffrax adjoint is not different"):
        jax.grad(final_height)(1.0, True, adjoint=diffrax.RecursiveCheckpointAdjoint())


@pytest.mark.slow
def test_sampled_forces_with_jumps_and_ends_before_the_run():
    # traced samples: every sample time is a jump time (made_jump, a fresh first
    # stage); the second element's samples end at 0.15 s, before the run
    ends = jnp.array([0.25, 0.15, 0.3])
    lifts = jnp.array([12.0, 15.0, 18.0])

    def run(end, lift, batch_loop):
        ts = jnp.linspace(0.0, end, 7)
        F = lift * jnp.abs(jnp.sin(20 * ts))[:, None, None] * (LIFT / 15.0)[None]
        force = eo.SampledForce(ts, F)
        return _two_body(MODEL.stiffness, force, Y0, 400, batch_loop=batch_loop)

    plain, loop = _both(run, ends, lifts)
    outside = eo.Status.OUTSIDE_FORCE_SAMPLES
    np.testing.assert_array_equal(plain.status, [0, outside, 0])
    _assert_same(plain, loop)
    # two at a time: the third starts (its first stage evaluated) where one stops
    queued = jax.vmap(lambda *a: run(*a, batch_loop=2))(ends, lifts)
    _assert_same(plain, queued)


@pytest.mark.slow
def test_gimbal_lock_and_collapsed_link_in_a_batch():
    # two bodies rushing together through a link of rest length 0.1 m (collapses
    # at the fast speeds), both spinning about their x axis (gimbal lock at the
    # fast spin); the last pair starts collapsed (not simulated)
    bodies = [eo.RigidBody(1.0, (0.1, 0.1, 0.1))] * 2
    link = eo.Connection(0, 1, [100.0] * 6, [0.0] * 6, rest_length=0.1)
    model = eo.MobileModel(bodies, [link], gravity=0.0)

    def run(speed, spin, gap, batch_loop):
        y0 = jnp.array([[0.0, 0, 0, *UP], [0.0, 0, 0, *UP]])
        y0 = y0.at[0, 0].set(gap / 2).at[1, 0].set(-gap / 2)
        ydot0 = jnp.zeros_like(y0).at[0, 0].set(-speed / 2).at[1, 0].set(speed / 2)
        ydot0 = ydot0.at[:, 4].set(spin)
        # (Tsit5: the solver these statuses and step counts were set on)
        return run_tight(
            model, y0, ydot0, 0.3, throw=False, batch_loop=batch_loop, solver=SOLVER
        )

    speeds = jnp.array([2.0, 0.5, 0.5, 0.5])
    spins = jnp.array([0.0, 0.0, 8.0, 0.0])
    gaps = jnp.array([0.1, 0.1, 0.1, 0.0])
    plain, loop = _both(run, speeds, spins, gaps)
    collapsed = eo.Status.LINK_COLLAPSED
    statuses = [collapsed, 0, eo.Status.GIMBAL_LOCK, collapsed]
    np.testing.assert_array_equal(plain.status, statuses)
    np.testing.assert_array_equal(plain.event_index, [0, -1, 0, 0])
    assert float(plain.event_time[3]) == 0.0
    _assert_same(plain, loop, **TIGHT)
    # the lanes that ran are those of a batch without the collapsed start
    three = jax.vmap(lambda *a: run(*a, batch_loop=True))(
        speeds[:3], spins[:3], gaps[:3]
    )
    np.testing.assert_array_equal(loop.y[:3], three.y)


@pytest.mark.slow
@pytest.mark.parametrize(
    ("solver", "rtol"),
    [(diffrax.Dopri5(), 1e-8), (diffrax.Dopri8(), 1e-8), (diffrax.Heun(), 1e-6)],
    ids=["dopri5", "dopri8", "heun"],
)
def test_prescribed_motion_and_other_solvers(solver, rtol):
    # the grasp held still (its reaction reported), the object free; Heun has no
    # first-same-as-last stage (its first is evaluated in each step), and at a
    # second order a looser tolerance
    motion = hold(jnp.zeros((2, 6), bool).at[1].set(True), Y0)
    scale = jnp.array([1.0, 3.0])[:, None, None] * MODEL.stiffness[None]

    def run(stiffness, batch_loop):
        model = eqx.tree_at(lambda m: m.stiffness, MODEL, stiffness)
        return eo.simulate(
            model,
            Y0.at[0, 2].add(0.01),
            jnp.zeros_like(Y0),
            SMALL_TS,
            solver=solver,
            rtol=rtol,
            prescribed=motion,
            throw=False,
            batch_loop=batch_loop,
        )

    plain, loop = _both(run, scale)
    np.testing.assert_array_equal(plain.status, [0, 0])
    _assert_same(plain, loop, rtol=rtol)
