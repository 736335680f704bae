"""Faults during a run: NaN or inf, a collapsed step size and forces sampled over too
short a time are stopped at once with their own status, one bad element of a batch
leaves the others alone (with and without the compilation cache), and force
callables that return no real numbers are refused with a message about forces."""

import contextlib

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SMALL_TS, small_two_body_model, two_body_run

import elasticoop as eo
from elasticoop._cache import compilation_cache

# The inputs of `two_body_run`: a lift on the grasp of a two-body model.
MODEL, Y0 = small_two_body_model()
YDOT0 = jnp.zeros_like(Y0).at[1, 2].set(0.5)
LIFT = jnp.array([[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]])


class Switch(eo.AbstractForce):
    """`before` up to `t_switch`, `after` from then on (one compilation for every
    value)."""

    t_switch: jax.Array
    before: jax.Array
    after: jax.Array

    def __call__(self, t, y, ydot):
        return jnp.where(t > self.t_switch, self.after, self.before)


# The collapse tests were set on Tsit5 at rtol 1e-8: which jump a solver can still
# pass in tiny steps depends on its order and tolerance.
SWITCHED_OPTIONS = eo.SimulationOptions("tsit5", 1e-8, 1e-10)


def _switched(after, options=None):
    force = Switch(jnp.array(0.05), LIFT, after)
    return eo.simulate(
        MODEL, Y0, YDOT0, SMALL_TS, forces=force, throw=False, options=options
    )


@pytest.mark.slow
@pytest.mark.parametrize("cache", [False, True], ids=["plain", "cache"])
def test_one_bad_element_of_a_batch_leaves_the_others_alone(cache, tmp_path):
    # Element 0 is `two_body_run`; element 1 has a NaN force, element 2 a NaN in the
    # initial state of body 1. The compilation cache switches equinox's runtime
    # checks to NaN mode, which must change nothing here.
    single = two_body_run()[0]
    forces = jnp.stack([LIFT, LIFT.at[0, 2].set(jnp.nan), LIFT])
    y_init = jnp.stack([Y0, Y0, Y0.at[1, 4].set(jnp.nan)])

    def run(F, y, throw=None):
        return eo.simulate(MODEL, y, YDOT0, SMALL_TS, forces=F, throw=throw)

    mode = compilation_cache(tmp_path) if cache else contextlib.nullcontext()
    with mode:
        batch = jax.vmap(run)(forces, y_init)
        # throw=True still raises (for the batch), whatever the error mode
        with pytest.raises(Exception, match="simulation stopped early"):
            jax.vmap(lambda F, y: run(F, y, throw=True).y)(
                forces, y_init
            ).block_until_ready()
    # the good lane is untouched by the bad ones: equal to the same element in a
    # batch of good elements only (vmap runs the batch loop, whose lanes are
    # independent) ...
    clean = jax.vmap(run)(jnp.stack([LIFT] * 3), jnp.stack([Y0] * 3))
    np.testing.assert_allclose(batch.y[0], clean.y[0], rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(batch.work[0], clean.work[0], rtol=1e-13, atol=1e-15)
    # ... and the single run (diffrax's loop) within the solver's tolerance: the
    # batch loop takes the same steps, rounded differently (tests/test_batch_loop.py)
    np.testing.assert_allclose(batch.y[0], single.y, rtol=1e-8, atol=1e-10)
    nonfinite = eo.Status.NONFINITE
    np.testing.assert_array_equal(batch.status, [0, nonfinite, nonfinite])
    np.testing.assert_array_equal(batch.event_index, [-1, 1, 1])
    assert np.all(np.isnan(batch.y[1:, 1:]))  # everything after the start
    assert float(batch.event_time[2]) == 0.0 and int(batch.n_steps[2]) == 1
    assert int(batch.n_steps[1]) < 100  # stopped at once, not after max_steps


@pytest.mark.slow
def test_nonfinite_force_stops_the_run_at_once():
    # NaN from t = 0.05 on: the run stops there (max_steps is 100_000), and up to
    # then it is the run with the lift throughout.
    traj = _switched(LIFT * jnp.nan)
    assert int(traj.n_steps) < 500
    assert int(traj.status) == eo.Status.NONFINITE
    np.testing.assert_allclose(float(traj.event_time), 0.05, rtol=1e-12)
    assert int(traj.event_index) == 1  # the grasp's force
    message = traj.message()
    assert "NaN or inf" in message and "forces of body 1" in message
    assert "t = 0.05 s" in message
    before = np.asarray(SMALL_TS) < 0.05
    lift = two_body_run()[0]
    np.testing.assert_allclose(traj.y[before], lift.y[before], rtol=1e-13)
    assert np.all(np.isnan(np.asarray(traj.y)[~before]))
    # concrete results raise, with the message
    force = Switch(jnp.array(0.05), LIFT, LIFT * jnp.inf)
    with pytest.raises(eo.SimulationError, match="NaN or inf stopped the run"):
        eo.simulate(MODEL, Y0, YDOT0, SMALL_TS, forces=force)


@pytest.mark.slow
def test_collapsed_step_size_is_a_solver_failure():
    # A jump of 1e12 N: no step, however short, meets the tolerances across it.
    traj = _switched(LIFT * 1e12, SWITCHED_OPTIONS)
    assert int(traj.n_steps) < 500
    assert int(traj.status) == eo.Status.SOLVER_FAILED
    np.testing.assert_allclose(float(traj.event_time), 0.05, rtol=1e-12)
    assert "step size collapsed" in traj.message()
    # a jump the solver can pass (in tiny steps) still passes
    assert int(_switched(LIFT * 1e9, SWITCHED_OPTIONS).status) == eo.Status.SUCCESS


def test_max_steps_message_advises_max_steps_not_an_implicit_solver():
    traj = two_body_run()[0]
    traj = eqx.tree_at(
        lambda t: (t.status, t.event_time),
        traj,
        (jnp.asarray(eo.Status.MAX_STEPS_REACHED, jnp.int32), jnp.asarray(0.1)),
    )
    message = traj.message()
    assert "raise max_steps" in message and "time span" in message
    assert "implicit" not in message


@pytest.mark.slow
def test_sampled_force_is_not_extrapolated_under_jit():
    # The same lift, sampled on [0, 0.1] (the run goes to 0.2) and on [0.01, 0.2].
    @eqx.filter_jit
    def run(force):
        return eo.simulate(MODEL, Y0, YDOT0, SMALL_TS, forces=force)

    samples = jnp.stack([LIFT, LIFT])
    traj = run(eo.SampledForce(jnp.array([0.0, 0.1]), samples))
    np.testing.assert_allclose(float(traj.event_time), 0.1, rtol=1e-12)
    assert int(traj.status) == eo.Status.OUTSIDE_FORCE_SAMPLES
    before = np.asarray(SMALL_TS) < 0.1 - 1e-12
    lift = two_body_run()[0]
    np.testing.assert_allclose(traj.y[before], lift.y[before], rtol=1e-7)
    assert np.all(np.isnan(np.asarray(traj.y)[~before]))
    assert "outside the times sampled" in traj.message()
    late = run(eo.SampledForce(jnp.array([0.01, 0.2]), samples))
    assert int(late.status) == eo.Status.OUTSIDE_FORCE_SAMPLES
    assert float(late.event_time) == 0.0 and np.all(np.isnan(late.y))
    covering = run(eo.SampledForce(jnp.array([0.0, 0.2]), samples))
    assert int(covering.status) == eo.Status.SUCCESS
    np.testing.assert_allclose(covering.y, lift.y, rtol=1e-7)


def _returns(value):
    def force(t, y, ydot):
        return value

    return force


@pytest.mark.parametrize(
    "value, problem",
    [
        (None, "NoneType None"),
        ("lift", "str 'lift'"),
        (np.asarray(LIFT) * (1 + 1j), "complex values"),
        (jnp.ones((1, 6), bool), "dtype bool"),
    ],
    ids=["None", "str", "complex", "bool"],
)
def test_force_callable_must_return_real_numbers(value, problem):
    with pytest.raises(ValueError, match="forces: the callable") as info:
        eo.simulate(MODEL, Y0, YDOT0, SMALL_TS, forces=_returns(value))
    assert "_returns.<locals>.force must return real numbers" in str(info.value)
    assert problem in str(info.value)


def test_custom_force_must_give_an_array():
    class Nothing(eo.AbstractForce):
        def __call__(self, t, y, ydot):
            return None

    with pytest.raises(ValueError, match=r"forces \(Nothing\) must give an array"):
        eo.simulate(MODEL, Y0, YDOT0, SMALL_TS, forces=Nothing())
