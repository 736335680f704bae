"""Where in its last step a run stopped: the zero crossing of the event that ended it.

`simulate` hands its stop conditions to `diffrax.Event` without a root finder:
diffrax then checks each condition at the end of every step and ends the solve at
the end of the step in which one changed sign. `locate_event` then finds the
crossing inside that step, once, after the loop and outside differentiation: by
bisection of the step (`rtol = atol = 1e-14`; every condition falls from positive
to non-positive in it) on the cubic Hermite interpolant of $Y$ through
$Y, \\dot Y$ at both ends of the step. The conditions depend on $Y$ only (the
orientation's regularity, the link lengths, time), and the interpolant needs no
evaluation of the right-hand side.

Bisection rather than Newton's method: optimistix's Newton solves its linear
system with lineax, whose Jacobian operator fails equinox's closure-conversion
check inside `jax.shard_map`, where `run_study` runs each device's samples. A
bisection needs no derivative; about 40 halvings of a step take it to 1e-14 s (at
most 64, one unit in the last place), once per run.

Why not diffrax's root finder: it is part of the solve, so under `jax.grad` its
implicit derivative is traced, transposed and compiled with it, and the dense
output of each step is kept for it through the loop: runs, their compilation and
that of their gradients take longer with it. The crossing time is not
differentiated: a run that stops early has NaN outputs after it, so a loss over it
has no gradient to give. The interpolant is one order below the solver's own (its
error is $O(h^4)$ in the step $h$); the event times of `tests/test_errors.py` (a
uniform spin and a sinusoidal collapse, against their closed forms) agree to 1e-8.

The start $(t_0, Y_0, \\dot Y_0)$ of the last step is kept by the step-size
controller (`StepRecord`).
"""

from collections.abc import Callable, Sequence
from typing import Any, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import optimistix as optx
from jaxtyping import Array, Bool

from .._custom_types import Scalar, State

_T = TypeVar("_T")

# bisection of the step in which a condition fell to zero (see the docstring);
# optimistix's `norm` is a class variable, which mypy takes for a field
ROOT_FINDER: optx.Bisection = optx.Bisection(  # type: ignore[call-arg]
    rtol=1e-14, atol=1e-14, flip=True
)
# Halvings of the step at most: 64 reach one unit in the last place of any step,
# where a condition's rounding keeps it from falling below `atol`.
MAX_HALVINGS = 64


def hermite(
    t: Scalar,
    t0: Scalar,
    t1: Scalar,
    y0: State,
    v0: State,
    y1: State,
    v1: State,
) -> tuple[State, State]:
    """The cubic Hermite interpolant through $y(t_0) = y_0$, $\\dot y(t_0) = v_0$,
    $y(t_1) = y_1$, $\\dot y(t_1) = v_1$, and its derivative, at $t$."""
    h = t1 - t0
    s = (t - t0) / h
    s2 = s * s
    s3 = s2 * s
    y = (
        (2 * s3 - 3 * s2 + 1) * y0
        + (s3 - 2 * s2 + s) * h * v0
        + (3 * s2 - 2 * s3) * y1
        + (s3 - s2) * h * v1
    )
    ydot = (
        (6 * s2 - 6 * s) * (y0 - y1) / h
        + (3 * s2 - 4 * s + 1) * v0
        + (3 * s2 - 2 * s) * v1
    )
    return y, ydot


def locate_event(
    t0: Scalar,
    t1: Scalar,
    start: tuple[State, State],
    end: tuple[State, State],
    args: Any,
    cond_fns: Sequence[Callable[[Scalar, State, Any], Scalar]],
    triggered: Sequence[Bool[Array, ""]],
) -> tuple[Scalar, State, State]:
    """The time $t_e \\in [t_0, t_1]$ where the triggered condition of `cond_fns`
    (functions of $t$, $Y$ and `args`) crosses zero in the step from $t_0$ to
    $t_1$, whose ends hold the states `start` and `end` ($Y, \\dot Y$), and the
    interpolated $Y, \\dot Y$ there.

    `triggered` is diffrax's `Solution.event_mask` (at most one true). With none
    triggered, $t_e = t_1$. Nothing of it is differentiated.
    """
    t0, t1, start, end, args = _without_gradient((t0, t1, start, end, args))
    mask = jnp.stack(list(triggered))

    def distance(t, _):
        y, _ = hermite(t, t0, t1, *start, *end)
        values = jnp.stack([jnp.asarray(fn(t, y, args), t.dtype) for fn in cond_fns])
        value = jnp.sum(jnp.where(mask, values, 0.0))
        return jnp.where(jnp.any(mask), value, t1 - t)

    root: optx.Solution = optx.root_find(
        distance,
        ROOT_FINDER,
        y0=t1,
        options=dict(lower=t0, upper=t1),
        max_steps=MAX_HALVINGS,
        throw=False,
    )
    t_event = jnp.clip(root.value, t0, t1)
    return t_event, *hermite(t_event, t0, t1, *start, *end)


def _without_gradient(tree: _T) -> _T:
    arrays, rest = eqx.partition(tree, eqx.is_inexact_array)
    return eqx.combine(jax.lax.stop_gradient(arrays), rest)
