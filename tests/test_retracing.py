"""Compiled once per structure: new values of the same structure never retrace.

A model, a state, a time grid or forces with new values but the same structure
(bodies, connections, convention, shapes, solver settings) reuse the compiled
solve; so do a second `Study` (tests/test_montecarlo.py) and a second fit of the
same problem (tests/test_identify.py). Counted with `eqx.debug.get_num_traces`.
"""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from helpers import run_tight, three_body_model, three_body_state

from elasticoop import _simulate


def test_a_new_model_of_the_same_structure_does_not_retrace():
    y0 = three_body_state()
    first = run_tight(three_body_model(), y0, jnp.zeros_like(y0), 0.5)
    traces = eqx.debug.get_num_traces(_simulate._solve)
    assert traces >= 1
    # built anew from other numbers: other stiffness, masses, state and time span
    stiffer = three_body_model(stiffness=[(900.0,) * 3 + (30.0,) * 3] * 2)
    y1 = three_body_state(spread=0.45, height=1.2)
    second = run_tight(
        stiffer, y1, 0.1 * jnp.ones_like(y1), 0.4, forces=np.ones((2, 6))
    )
    assert eqx.debug.get_num_traces(_simulate._solve) == traces
    # ... and really ran the new values
    assert float(second.ts[-1]) == 0.4
    np.testing.assert_array_equal(second.y[0], y1)
    assert not np.allclose(first.y[-1], second.y[-1])
