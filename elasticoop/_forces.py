"""Contact forces $F_c$ on the contact bodies, and wrench -> generalized force."""

import abc
import warnings
from collections.abc import Callable

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._custom_types import (
    ArrayInput,
    Forces,
    Scalar,
    State,
    TimeLike,
    Times,
    Vector6,
)
from ._rotations import get_rotation
from ._validation import as_float_array, check_times, is_concrete


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
    """A constant generalized force `F` of shape `(m, 6)` or `(m + 1, 6)`."""

    F: Forces

    def __init__(self, F: ArrayInput):
        self.F = jnp.asarray(as_float_array(F, "ConstantForce.F", (None, 6)))

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
    times `ts`, interpolated linearly (`diffrax.LinearInterpolation`). Simulated
    times must lie within `ts`.

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
        F = as_float_array(F, "SampledForce.F", (ts.shape[0], None, 6))
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
        return diffrax.LinearInterpolation(ts=self.ts, ys=self.F).evaluate(t)


class FeedbackForce(AbstractForce):
    """A force from a callable `fn(t, y, ydot) -> (m, 6)`, e.g. a feedback law."""

    fn: Callable[..., ArrayInput] = eqx.field(static=True)

    def __call__(self, t: TimeLike, y: State, ydot: State) -> Forces:
        return jnp.asarray(self.fn(t, y, ydot), dtype=jnp.float64)


def jump_times(force: AbstractForce | None) -> Times | None:
    """Times at which `force` has kinks, handed to the step-size controller
    (`SampledForce.jump_ts`; none otherwise)."""
    return force.jump_ts if isinstance(force, SampledForce) else None


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
    value at `ts[0]` must have shape `(m, 6)` or `(m + 1, 6)`, and a
    `SampledForce` must cover the times `ts` (checked where both are concrete).
    `owner` prefixes the field name in errors (`"Study."` gives `Study.forces`)."""
    force = as_force(forces)
    if force is None:
        return None
    n_bodies = y_init.shape[0]
    check_force_shape(
        jax.eval_shape(force, ts[0], y_init, ydot_init).shape, n_bodies, owner
    )
    if isinstance(force, SampledForce) and is_concrete(force.ts, ts):
        lo, hi = float(force.ts[0]), float(force.ts[-1])
        if float(ts[0]) < lo or float(ts[-1]) > hi:
            raise ValueError(
                f"{owner}ts spans [{float(ts[0])}, {float(ts[-1])}] s but the "
                f"{owner}forces (SampledForce) samples only cover [{lo}, {hi}] s"
            )
    return force


def minimum_jerk(s: Scalar) -> Scalar:
    """$10s^3 - 15s^4 + 6s^5$ on $[0, 1]$, held at 0 and 1 outside."""
    s = jnp.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


class PoseTracking(AbstractForce):
    """Manipulators as PD controllers on the grasp poses plus a weight feedforward.

    Grasp body $i$ is driven towards $Y_{i}^{ref}(t) = Y_{i}(0) + h\\,s(t/T)\\,e_z$
    ($s$ the minimum-jerk profile, its rate by forward-mode autodiff):
    $F_i = F^{ff} + K_p (Y_i^{ref} - Y_i) + K_d (\\dot Y_i^{ref} - \\dot Y_i)$,
    gains per coordinate (translations [N/m], Euler angles [N m/rad]).
    """

    y_ref: Float[Array, "m 6"]  # initial grasp poses
    feedforward: Float[Array, "m 6"]
    kp: Float[Array, "6"]
    kd: Float[Array, "6"]
    height: Scalar
    duration: Scalar

    def __call__(self, t: TimeLike, y: State, ydot: State) -> Forces:
        lift = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        s, rate = jax.jvp(
            lambda t: minimum_jerk(t / self.duration), (t,), (jnp.ones_like(t),)
        )
        ref = self.y_ref + self.height * s * lift
        ref_rate = self.height * rate * lift
        grasps, rates = y[1:], ydot[1:]
        return (
            self.feedforward + self.kp * (ref - grasps) + self.kd * (ref_rate - rates)
        )
