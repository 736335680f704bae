"""Contact forces $F_c$ on the contact bodies, and wrench -> generalized force."""

import abc
import warnings
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._custom_types import (
    ArrayInput,
    BoolScalar,
    Forces,
    Scalar,
    State,
    TimeLike,
    Times,
    Vector6,
)
from ._rotations import get_rotation
from ._validation import as_float_array, check_times, is_concrete, xp


class AbstractForce(eqx.Module):
    """Generalized forces applied by the manipulators.

    `force(t, y, ydot)` returns shape `(m, 6)` (contact bodies 1..m; the object gets
    $F_0 = 0$) or `(m + 1, 6)` (all bodies, row 0 a disturbance on the object). Each
    row holds three world-axis force components [N] and three generalized torques
    conjugate to the Euler angles [N m] (see `generalized_wrench`).
    """

    @abc.abstractmethod
    def __call__(self, t: TimeLike, y: State, ydot: State) -> Forces:
        pass


class ConstantForce(AbstractForce):
    """A constant generalized force `F` of shape `(m, 6)` or `(m + 1, 6)`.

    Concrete `F` must be finite; traced `F` (under `jit`/`vmap`) is not checked
    here: `simulate` reports NaN or inf forces as `Status.NONFINITE`."""

    F: Forces

    def __init__(self, F: ArrayInput):
        self.F = jnp.asarray(
            as_float_array(F, "ConstantForce.F", (None, 6), check_traced=False)
        )

    def __call__(self, t: TimeLike, y: State | None, ydot: State | None) -> Forces:
        return self.F


# A sample is a kink of the linear interpolant when, in some component, the slope
# changes there by more than KINK_RTOL times that component's largest slope; at most
# MAX_JUMP_TIMES jump times (the largest kinks, and the first and last sample) are
# handed to the step-size controller.
KINK_RTOL = 1e-2
MAX_JUMP_TIMES = 10_000


def kink_times(
    ts: Float[np.ndarray, " times"], F: Float[np.ndarray, "times ..."]
) -> Float[np.ndarray, " jumps"]:
    """The times at which the linear interpolant of samples `F` at times `ts` has a
    kink worth stepping onto: the first and last sample, and every sample $k$ where
    a component's slope $s_k = (F_{k+1} - F_k)/(t_{k+1} - t_k)$ changes by
    $|s_k - s_{k-1}| >$ `KINK_RTOL` $\\max_j |s_j|$ (that component's largest
    slope). Densely sampled smooth data has no such kinks; collinear samples neither.
    When more than `MAX_JUMP_TIMES` remain, the largest relative kinks are kept
    (with a warning); the step-size controller's error control resolves the rest."""
    n = ts.shape[0]
    values = F.reshape(n, -1)
    dt = np.diff(ts)
    relative = np.zeros(max(n - 2, 0))
    for column in values.T:  # one component at a time: memory O(samples)
        slopes = np.diff(column) / dt
        largest = np.max(np.abs(slopes)) if slopes.size else 0.0
        if largest > 0:
            change = np.abs(np.diff(slopes)) / largest
            np.maximum(relative, change, out=relative)
    kinks = np.flatnonzero(relative > KINK_RTOL)
    room = MAX_JUMP_TIMES - 2
    if kinks.size > room:
        warnings.warn(
            f"SampledForce: {kinks.size} of the {n} samples are kinks of the "
            f"linear interpolant (slope changes over {KINK_RTOL:g} of the largest "
            f"slope); only the {room} largest are handed to the step-size "
            f"controller as jump times, its error control resolves the others. "
            f"Smooth or resample the samples for a faster run.",
            stacklevel=2,
        )
        kinks = np.sort(kinks[np.argpartition(relative[kinks], -room)[-room:]])
    return ts[np.concatenate([[0], kinks + 1, [n - 1]])]


class SampledForce(AbstractForce):
    """Force samples `F` of shape `(len(ts), m, 6)` (or `(len(ts), m + 1, 6)`) at
    times `ts`, interpolated linearly (`diffrax.LinearInterpolation`).

    Simulated times must lie within `ts`; nothing is extrapolated. `simulate` (and
    `Study`, `Experiment` and scenario files) refuse a time span the samples do not
    cover where the times are concrete; under `jit`/`vmap` a run that reaches a time
    outside the samples stops there with `Status.OUTSIDE_FORCE_SAMPLES`. Concrete
    samples must be finite; traced ones that are not give `Status.NONFINITE`.

    `jump_ts` are the times passed to the step-size controller as jump times, so
    that an adaptive solver steps onto the kinks of the interpolant. By default
    (`jump_ts=None`) they are the samples where the slope changes markedly
    (`kink_times`), not every sample: densely sampled smooth data costs no more
    steps than its shape needs. A `SampledForce` built from traced values (inside
    `jit`) hands every sample time. `jump_ts` belong to the samples given here: a
    `Study` or `identify` that replaces `F` keeps them (they only guide the step
    size; accuracy comes from the error control)."""

    ts: Times
    F: Float[Array, "times rows 6"]
    jump_ts: Float[Array, " jumps"]

    def __init__(
        self, ts: ArrayInput, F: ArrayInput, jump_ts: ArrayInput | None = None
    ):
        ts = check_times(ts, "SampledForce.ts")
        F = as_float_array(
            F, "SampledForce.F", (ts.shape[0], None, 6), check_traced=False
        )
        self.ts = jnp.asarray(ts)
        self.F = jnp.asarray(F)
        if jump_ts is not None:
            self.jump_ts = jnp.sort(
                jnp.asarray(as_float_array(jump_ts, "SampledForce.jump_ts", (None,)))
            )
        elif is_concrete(ts, F):
            self.jump_ts = jnp.asarray(kink_times(np.asarray(ts), np.asarray(F)))
        else:
            self.jump_ts = self.ts

    def __call__(self, t: TimeLike, y: State | None, ydot: State | None) -> Forces:
        import diffrax  # where a run needs it (checking a scenario does not)

        return diffrax.LinearInterpolation(ts=self.ts, ys=self.F).evaluate(t)


class FeedbackForce(AbstractForce):
    """A force from a callable `fn(t, y, ydot) -> (m, 6)`, e.g. a feedback law. It
    must return real numbers (an array, or nested lists, of floats or integers)."""

    fn: Callable[..., ArrayInput] = eqx.field(static=True)

    def __call__(self, t: TimeLike, y: State, ydot: State) -> Forces:
        return real_forces(self.fn(t, y, ydot), self.fn)


def _callable_name(fn: Callable) -> str:
    return getattr(fn, "__qualname__", None) or type(fn).__name__


def real_forces(value: object, fn: Callable) -> Float[Array, "..."]:
    """What the force callable `fn` returned, `value`, as a float64 array; a
    `ValueError` naming `fn` unless it holds real numbers (`None`, strings, objects
    and complex numbers are refused: a complex force has no physical meaning, and
    casting it would silently drop its imaginary part)."""
    problem = None
    try:
        arr = jnp.asarray(value)
    except (TypeError, ValueError):
        problem = f"{type(value).__name__} {value!r}"
    else:
        if jnp.issubdtype(arr.dtype, jnp.complexfloating):
            problem = f"complex values (dtype {arr.dtype})"
        elif not (
            jnp.issubdtype(arr.dtype, jnp.floating)
            or jnp.issubdtype(arr.dtype, jnp.integer)
        ):
            problem = f"values of dtype {arr.dtype}"
    if problem is not None:
        raise ValueError(
            f"forces: the callable {_callable_name(fn)} must return real numbers, an "
            f"array of shape (m, 6) or (m + 1, 6), but returned {problem}"
        )
    return arr.astype(jnp.float64)


def jump_times(force: AbstractForce | None) -> Times | None:
    """Times at which `force` has kinks, handed to the step-size controller
    (`SampledForce.jump_ts`; none otherwise)."""
    return force.jump_ts if isinstance(force, SampledForce) else None


def sampled_interval(force: AbstractForce | None) -> tuple[Scalar, Scalar] | None:
    """The times `(first, last)` within which `force` is defined (the first and the
    last sample of a `SampledForce`); `None` for a force defined at all times."""
    if isinstance(force, SampledForce):
        return force.ts[0], force.ts[-1]
    return None


def check_coverage(
    force: AbstractForce | None,
    ts: Float[Array | np.ndarray, " times"],
    owner: str = "",
) -> None:
    """A `ValueError` unless `force` is defined over the times `ts` (a
    `SampledForce` must have samples from `ts[0]` to `ts[-1]`). Checked where both
    are concrete; under `jit`/`vmap`, `simulate` reports a run that leaves the
    samples as `Status.OUTSIDE_FORCE_SAMPLES` instead. `owner` prefixes the field
    names in the message (`"Study."` gives `Study.ts`)."""
    interval = sampled_interval(force)
    if interval is None or not is_concrete(interval, ts):
        return
    lo, hi = (float(t) for t in interval)
    if float(ts[0]) < lo or float(ts[-1]) > hi:
        raise ValueError(
            f"{owner}ts spans [{float(ts[0])}, {float(ts[-1])}] s but the "
            f"{owner}forces (SampledForce) samples only cover [{lo}, {hi}] s; "
            f"samples are not extrapolated"
        )


def as_force(
    forces: AbstractForce | Callable[..., ArrayInput] | ArrayInput | None,
) -> AbstractForce | None:
    """Accept `None`, an `AbstractForce`, a callable or a constant array."""
    if forces is None or isinstance(forces, AbstractForce):
        return forces
    if callable(forces):
        return FeedbackForce(forces)
    return ConstantForce(forces)


def generalized_wrench(
    angles: ArrayInput,
    force: ArrayInput,
    torque: ArrayInput,
    frame: str = "world",
    convention: str = "zxz",
) -> Vector6:
    """Map a physical wrench at a body's mass centre to its generalized force.

    The force enters unchanged (world axes); the torque $\\tau$ maps through the
    virtual-work identity
    $\\tau\\cdot\\omega = Q_{\\mathcal A}\\cdot\\dot{\\mathcal A}$:
    $Q_{\\mathcal A} = L_\\omega^T \\tau$ for a body-frame torque and
    $L_\\omega^T R^T \\tau$ for a world-frame one.

    **Arguments:**

    - `angles`: the body's Euler angles.
    - `force`: force [N], `frame` axes (a body-frame force is rotated to world).
    - `torque`: torque [N m], `frame` axes.
    - `frame`: `"world"` or `"body"`.
    - `convention`: `"zxz"` or `"rpy"`.

    **Returns:** the 6-vector $(F_x, F_y, F_z, Q_{a_1}, Q_{a_2}, Q_{a_3})$.
    """
    if frame not in ("world", "body"):
        raise ValueError(f"frame must be 'world' or 'body', got {frame!r}")
    rotation = get_rotation(convention)
    angles, force, torque = (
        jnp.asarray(as_float_array(v, name, (3,)))
        for v, name in ((angles, "angles"), (force, "force"), (torque, "torque"))
    )
    R = rotation.matrix(angles)
    L = rotation.angular_velocity_matrix(angles)
    if frame == "world":
        torque = R.T @ torque
    else:
        force = R @ force
    return jnp.concatenate([force, L.T @ torque])


def pad_to_bodies(F: Forces, n_bodies: int) -> State:
    """Return `(bodies, 6)` forces from `(m, 6)` contact forces or `(m + 1, 6)`."""
    if F.shape == (n_bodies - 1, 6):
        return jnp.concatenate([jnp.zeros((1, 6), F.dtype), F])
    return F


def check_force_shape(shape: tuple[int, ...], n_bodies: int, owner: str = "") -> None:
    """Generalized forces must have shape `(m, 6)` or `(m + 1, 6)`."""
    m = n_bodies - 1
    if tuple(shape) not in ((m, 6), (n_bodies, 6)):
        raise ValueError(
            f"{owner}forces must give shape ({m}, 6) for the m = {m} contact bodies "
            f"(or ({n_bodies}, 6) including the object), got {tuple(shape)}"
        )


def check_force(
    forces: AbstractForce | Callable[..., ArrayInput] | ArrayInput | None,
    y_init: State,
    ydot_init: State,
    ts: Float[Array | np.ndarray, " times"],
    owner: str = "",
) -> AbstractForce | None:
    """`forces` as an `AbstractForce` (or `None`), checked against the system: its
    value at `ts[0]` must be real numbers of shape `(m, 6)` or `(m + 1, 6)`, and a
    `SampledForce` must cover the times `ts` (`check_coverage`).
    `owner` prefixes the field name in errors (`"Study."` gives `Study.forces`)."""
    force = as_force(forces)
    if force is None:
        return None
    n_bodies = y_init.shape[0]
    value = jax.eval_shape(force, jax.ShapeDtypeStruct((), ts.dtype), y_init, ydot_init)
    dtype = getattr(value, "dtype", None)
    if dtype is None or not jnp.issubdtype(dtype, jnp.floating):
        got = type(value).__name__ if dtype is None else f"dtype {dtype}"
        raise ValueError(
            f"{owner}forces ({type(force).__name__}) must give an array of "
            f"floating-point numbers, got {got}"
        )
    check_force_shape(value.shape, n_bodies, owner)
    check_coverage(force, ts, owner)
    return force


def minimum_jerk(s: Scalar) -> Scalar:
    """$10s^3 - 15s^4 + 6s^5$ on $[0, 1]$, held at 0 and 1 outside."""
    s = jnp.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


def _float64(value: ArrayInput) -> Float[Array, "..."]:
    """`value` as a float64 JAX array (a field converter)."""
    return jnp.asarray(value, dtype=jnp.float64)


class PoseTracking(AbstractForce):
    """Manipulators as PD controllers on the grasp poses plus a weight feedforward.

    Grasp body $i$ is driven towards
    $Y_{i}^{ref}(t) = Y_{i}(t_0) + h\\,s\\big((t - t_0)/T\\big)\\,e_z$
    ($s$ the minimum-jerk profile, its rate by forward-mode autodiff; $t_0$ =
    `start`, the time the lift begins, 0 by default):
    $F_i = F^{ff} + K_p (Y_i^{ref} - Y_i) + K_d (\\dot Y_i^{ref} - \\dot Y_i)$,
    gains per coordinate (translations [N/m], Euler angles [N m/rad]).

    **Fields:** `y_ref` the grasps' poses $Y_i(t_0)$ and `feedforward` $F^{ff}$,
    both `(m, 6)`; `kp`, `kd` `(6,)`; `height` $h$ [m]; `duration` $T > 0$ [s];
    `start` $t_0$ [s]. Every field is stored as a float64 array, whatever it is
    given as (Python numbers or lists too), and checked when concrete: the force
    is then a pytree of arrays that can be differentiated, `vmap`-ped and batched
    like any other input (a batch of forces: build one per set of values and stack
    their fields, `jax.tree.map(lambda *x: jnp.stack(x), *forces)`, or build them
    inside the `vmap`).
    """

    y_ref: Float[Array, "m 6"] = eqx.field(converter=_float64)  # initial poses
    feedforward: Float[Array, "m 6"] = eqx.field(converter=_float64)
    kp: Float[Array, "6"] = eqx.field(converter=_float64)
    kd: Float[Array, "6"] = eqx.field(converter=_float64)
    height: Scalar = eqx.field(converter=_float64)
    duration: Scalar = eqx.field(converter=_float64)
    start: Scalar = eqx.field(converter=_float64, default=0.0)

    def __check_init__(self):
        m = self.y_ref.shape[0] if self.y_ref.ndim == 2 else None
        rows = self.feedforward.shape[:1] if self.feedforward.ndim == 2 else None
        if m is not None and rows is not None and rows != (m,):
            # (which of the two is wrong is not known here: both are named)
            raise ValueError(
                f"PoseTracking.y_ref and PoseTracking.feedforward must have one row "
                f"per manipulator each, got y_ref of shape {self.y_ref.shape} and "
                f"feedforward of shape {self.feedforward.shape} (the grasps' poses, "
                f"without the object's row)"
            )
        fields = ("y_ref", "feedforward", "kp", "kd", "height", "duration", "start")
        shapes = ((m, 6), (m, 6), (6,), (6,), (), (), ())
        for name, shape in zip(fields, shapes, strict=True):
            # shapes always; finite values where concrete
            as_float_array(
                getattr(self, name), f"PoseTracking.{name}", shape, check_traced=False
            )
        if is_concrete(self.duration) and not float(self.duration) > 0:
            raise ValueError(
                f"PoseTracking.duration must be > 0 [s], got {float(self.duration)!r}"
            )
        for name in ("kp", "kd"):  # a negative gain drives away from the pose
            gains = getattr(self, name)
            if is_concrete(gains) and np.any(np.asarray(gains) < 0):
                k = int(np.argmax(np.asarray(gains) < 0))
                raise ValueError(
                    f"PoseTracking.{name} must be >= 0 in every coordinate, got "
                    f"{float(gains[k])!r} in coordinate {k} (of x, y, z and the "
                    f"three angles)"
                )

    def __call__(self, t: TimeLike, y: State, ydot: State) -> Forces:
        lift = jnp.array([[0.0, 0.0, 1.0, 0.0, 0.0, 0.0]])  # (one row, for every grasp)
        s, rate = jax.jvp(
            lambda t: minimum_jerk((t - self.start) / self.duration),
            (t,),
            (jnp.ones_like(t),),
        )
        ref = self.y_ref + self.height * s * lift
        ref_rate = self.height * rate * lift
        grasps, rates = y[1:], ydot[1:]
        return (
            self.feedforward
            + self.kp[None] * (ref - grasps)
            + self.kd[None] * (ref_rate - rates)
        )


def force_admissible(force: AbstractForce | None) -> BoolScalar:
    """Whether a force's values pass its checks of construction other than
    finiteness (which `simulate` reports as `Status.NONFINITE`), traced or not:
    for values changed afterwards, e.g. a Monte Carlo draw. A `PoseTracking` lift
    needs a positive duration and gains >= 0; the other forces have no range to
    check."""
    if isinstance(force, PoseTracking):
        np_ = xp(force.duration, force.kp, force.kd)
        return (
            (np_.asarray(force.duration) > 0)
            & np_.all(np_.asarray(force.kp) >= 0)
            & np_.all(np_.asarray(force.kd) >= 0)
        )
    return True
