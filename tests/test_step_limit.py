"""A traced step limit (what identification's step budget is) stops a run as the
options' `max_steps` does: the same status, steps and outputs, from one compiled
program for every limit, alone and in the batch loop under `jax.vmap`."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import three_body_model, three_body_state

import elasticoop as eo
from elasticoop._simulate import _simulate

pytestmark = pytest.mark.slow  # a run compiled per static max_steps it is compared with

MODEL = three_body_model()
Y0 = three_body_state().at[1, :3].add(jnp.array([-0.01, 0.005, 0.01]))
YDOT0 = jnp.zeros_like(Y0)
TS = jnp.linspace(0.0, 0.2, 11)
OPTIONS = eo.SimulationOptions()


@jax.jit
def limited(y0, limit):
    """The run under a step limit, compiled once for every limit."""
    return _simulate(MODEL, y0, YDOT0, TS, None, OPTIONS, throw=False, step_limit=limit)


def capped(max_steps):
    """The same run with `max_steps` (a static setting) instead."""
    options = eo.SimulationOptions(max_steps=max_steps)
    return eo.simulate(MODEL, Y0, YDOT0, TS, options=options, throw=False)


def assert_same_run(a, b):
    assert int(a.status) == int(b.status)
    assert int(a.n_steps) == int(b.n_steps)
    np.testing.assert_array_equal(np.asarray(a.y), np.asarray(b.y))
    np.testing.assert_array_equal(np.asarray(a.ydot), np.asarray(b.ydot))
    np.testing.assert_array_equal(np.asarray(a.event_time), np.asarray(b.event_time))


def test_a_step_limit_stops_a_run_as_max_steps_does():
    # the steps the run needs, under the options' own max_steps as the limit
    steps = int(limited(Y0, jnp.asarray(OPTIONS.max_steps)).n_steps)
    assert steps > 20
    # below the steps the run needs it stops early; at or above them it ends
    for limit, status in [
        (steps - 4, eo.Status.MAX_STEPS_REACHED),
        (steps - 1, eo.Status.MAX_STEPS_REACHED),
        (steps, eo.Status.SUCCESS),
        (steps + 3, eo.Status.SUCCESS),
    ]:
        ours = limited(Y0, jnp.asarray(limit))
        assert int(ours.status) == status, limit
        assert_same_run(ours, capped(limit))
    assert limited._cache_size() == 1


def test_a_step_limit_in_the_batch_loop():
    """Under `jax.vmap` (the batch loop), each element stops at the limit where it
    needs more steps, as it does alone."""
    y0 = jnp.stack([Y0, Y0.at[2, 2].add(0.02), Y0.at[1, 4].add(0.05)])
    alone = [limited(y, jnp.asarray(OPTIONS.max_steps)) for y in y0]
    needed = sorted(int(t.n_steps) for t in alone)
    limit = jnp.asarray(needed[1])  # the element needing more steps stops early
    batch = jax.vmap(limited, in_axes=(0, None))(y0, limit)
    for k, y in enumerate(y0):
        one = limited(y, limit)
        assert int(batch.status[k]) == int(one.status)
        assert int(batch.n_steps[k]) == int(one.n_steps)
        np.testing.assert_allclose(batch.y[k], one.y, rtol=1e-12, atol=1e-14)
    stopped = np.asarray(batch.status) == eo.Status.MAX_STEPS_REACHED
    assert stopped.sum() >= 1 and (~stopped).sum() >= 2
