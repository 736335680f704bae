"""Motions of prescribed coordinates: any callable $t \\mapsto Y(t)$, or samples."""

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Bool

from ._custom_types import (
    ArrayInput,
    State,
    StateSeries,
    TimeLike,
    Times,
    Validated,
)
from ._validation import as_float_array, check_times, is_concrete


class AbstractMotion(eqx.Module):
    """A motion $t \\mapsto Y(t)$ of shape `(bodies, 6)`; its velocity and
    acceleration come from forward-mode autodiff in $t$, so it must be twice
    differentiable (at least piecewise)."""

    @abc.abstractmethod
    def __call__(self, t: TimeLike) -> State:
        raise NotImplementedError


class SplineMotion(AbstractMotion):
    """Natural cubic spline through samples $Y(t_k)$: $C^2$, so the prescribed
    velocity and acceleration are continuous (the acceleration is piecewise linear).

    On $[t_k, t_{k+1}]$, with $h_k = t_{k+1} - t_k$, $a = t_{k+1} - t$, $b = t - t_k$,

    $$S(t) = \\frac{M_k a^3 + M_{k+1} b^3}{6 h_k}
        + \\Big(\\frac{Y_k}{h_k} - \\frac{M_k h_k}{6}\\Big) a
        + \\Big(\\frac{Y_{k+1}}{h_k} - \\frac{M_{k+1} h_k}{6}\\Big) b,$$

    where the knot second derivatives $M_k$ solve the tridiagonal system
    $h_{k-1} M_{k-1} + 2(h_{k-1} + h_k) M_k + h_k M_{k+1}
    = 6\\big(\\frac{Y_{k+1} - Y_k}{h_k} - \\frac{Y_k - Y_{k-1}}{h_{k-1}}\\big)$
    (`lineax.Tridiagonal`) with natural ends $M_0 = M_n = 0$: the prescribed
    acceleration is zero at the first and last sample, so start and end the samples
    at rest or a little outside the simulated span.

    **Arguments:**

    - `ts`: sample times, strictly increasing, at least 2.
    - `y`: samples, shape `(len(ts), bodies, 6)`.

    Differentiable with respect to `y` (and `ts`).
    """

    ts: Times
    y: StateSeries
    second: StateSeries

    def __init__(self, ts: ArrayInput, y: ArrayInput):
        ts = check_times(ts, "SplineMotion.ts")
        y = as_float_array(y, "SplineMotion.y", (ts.shape[0], None, 6))
        self.ts = jnp.asarray(ts)
        self.y = jnp.asarray(y)
        self.second = _natural_second_derivatives(self.ts, self.y)

    def __call__(self, t: TimeLike) -> State:
        k = jnp.clip(
            jnp.searchsorted(self.ts, t, side="right") - 1, 0, len(self.ts) - 2
        )
        t0, t1 = self.ts[k], self.ts[k + 1]
        h = t1 - t0
        a, b = t1 - t, t - t0
        m0, m1 = self.second[k], self.second[k + 1]
        y0, y1 = self.y[k], self.y[k + 1]
        return (
            (m0 * a**3 + m1 * b**3) / (6 * h)
            + (y0 / h - m0 * h / 6) * a
            + (y1 / h - m1 * h / 6) * b
        )


def _natural_second_derivatives(ts: Times, y: StateSeries) -> StateSeries:
    n = ts.shape[0]
    if n < 3:
        return jnp.zeros_like(y)
    h = jnp.diff(ts)
    slope = jnp.diff(y, axis=0) / h[:, None, None]
    rhs = 6 * (slope[1:] - slope[:-1])  # (n - 2, bodies, 6)
    import lineax as lx  # where a spline needs it (checking a scenario does not)

    operator = lx.TridiagonalLinearOperator(2 * (h[:-1] + h[1:]), h[1:-1], h[1:-1])
    flat = rhs.reshape(n - 2, -1)
    solve = jax.vmap(
        lambda b: lx.linear_solve(operator, b, solver=lx.Tridiagonal()).value,
        in_axes=1,
        out_axes=1,
    )
    inner = solve(flat).reshape(rhs.shape)
    zero = jnp.zeros_like(y[:1])
    return jnp.concatenate([zero, inner, zero])


class _Callable(AbstractMotion):
    fn: Callable[[TimeLike], State]

    def __call__(self, t: TimeLike) -> State:
        return self.fn(t)


class PrescribedMotion(eqx.Module):
    """Coordinates driven along a given motion (kinematic driving).

    The coordinates where `mask` is true follow `motion`; the others are integrated.
    The generalized forces that realise the prescribed motion, the reactions
    $Q_p = [W\\ddot Y + w - G - F]_p$, are returned in `Trajectory.reaction`.

    **Arguments:**

    - `mask`: bool array `(bodies, 6)`, true for a prescribed coordinate (e.g. all
      rows of the contact bodies: the grasps follow the manipulators).
    - `motion`: a callable `t -> (bodies, 6)` (only the prescribed entries are used),
      twice differentiable in `t` by JAX — an `equinox.Module` if it carries arrays
      that should be differentiated or batched — or a `SplineMotion` of samples.

    $\\dot Y_p$ and $\\ddot Y_p$ come from forward-mode autodiff of `motion` in $t$.
    """

    motion: AbstractMotion
    mask_tuple: tuple[tuple[bool, ...], ...] = eqx.field(static=True)

    def __init__(
        self, mask: ArrayInput, motion: Validated[Callable[[TimeLike], State]]
    ):
        arr = np.asarray(mask)
        if arr.ndim != 2 or arr.shape[1] != 6 or arr.dtype != np.bool_:
            raise ValueError(
                "PrescribedMotion.mask must be a bool array of shape (bodies, 6), got "
                f"dtype {arr.dtype} and shape {arr.shape}"
            )
        if not callable(motion):
            raise ValueError(
                f"PrescribedMotion.motion must be callable t -> (bodies, 6), got "
                f"{motion!r}"
            )
        self.mask_tuple = tuple(tuple(bool(v) for v in row) for row in arr)
        self.motion = (
            motion if isinstance(motion, AbstractMotion) else _Callable(motion)
        )

    @property
    def mask(self) -> Bool[np.ndarray, "bodies 6"]:
        return np.array(self.mask_tuple, dtype=bool)

    @property
    def n_prescribed(self) -> int:
        return int(self.mask.sum())

    def state(self, t: TimeLike) -> tuple[State, State, State]:
        """$(Y(t), \\dot Y(t), \\ddot Y(t))$ of the motion, each `(bodies, 6)`."""
        t = jnp.asarray(t, dtype=jnp.float64)

        def position_velocity(s):
            return jax.jvp(self.motion, (s,), (jnp.ones_like(s),))

        (y, v), (_, a) = jax.jvp(position_velocity, (t,), (jnp.ones_like(t),))
        return y, v, a

    def impose(self, t: TimeLike, y: State, ydot: State) -> tuple[State, State, State]:
        """`y` and `ydot` with their prescribed entries replaced by the motion's at
        `t`, and the motion's $\\ddot Y(t)$."""
        y_p, ydot_p, yddot_p = self.state(t)
        mask = self.mask
        return jnp.where(mask, y_p, y), jnp.where(mask, ydot_p, ydot), yddot_p

    def check(self, n_bodies: int, t0: TimeLike, t1: TimeLike) -> None:
        """Validate against a model of `n_bodies` on the span `[t0, t1]`."""
        if self.mask.shape != (n_bodies, 6):
            raise ValueError(
                f"PrescribedMotion.mask must have shape ({n_bodies}, 6) for this "
                f"model, got {self.mask.shape}"
            )
        if not self.mask.any():
            raise ValueError("PrescribedMotion.mask prescribes no coordinate")
        shape = jax.eval_shape(self.motion, jnp.zeros(())).shape
        if shape != (n_bodies, 6):
            raise ValueError(
                f"PrescribedMotion.motion(t) must return shape ({n_bodies}, 6), got "
                f"{shape}"
            )
        if isinstance(self.motion, SplineMotion) and is_concrete(
            self.motion.ts, t0, t1
        ):
            lo, hi = float(self.motion.ts[0]), float(self.motion.ts[-1])
            if float(t0) < lo or float(t1) > hi:
                raise ValueError(
                    f"ts spans [{float(t0)}, {float(t1)}] s but the SplineMotion "
                    f"samples only cover [{lo}, {hi}] s"
                )
