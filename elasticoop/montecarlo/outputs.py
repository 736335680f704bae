"""What a study keeps of each simulated sample: trajectories or reductions.

An `Output` is any function of one (un-batched) `Trajectory` returning an array of
fixed shape, with names for its axes. A sample that stopped early has NaN after
its stop, so reductions over time (max, final value) come out NaN for it; such
samples are excluded from the statistics and counted in the summary.

Axis names shared with the trajectory export (`trajectory_to_xarray`) are labelled
in the results with the same vocabulary: `time` (the study's output times), `body`
(`object, contact1, ...`), `coordinate` (`x, y, z` and the convention's Euler
angles) and `connection` (`object-contact1`, ...).
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from .._models import MobileModel, deflection
from .._trajectory import Trajectory


class Output(eqx.Module):
    """A per-sample quantity `fn(trajectory) -> array` with axis names `dims`.

    An axis named `"time"` is labelled with the study's output times, `"body"`,
    `"coordinate"` and `"connection"` with the model's body, coordinate and
    connection names. A bare callable given to a study becomes `Output(fn)` with
    axes `name_0, name_1, ...`.

    `fn` may be any callable, also an `equinox.Module` holding arrays (they are
    traced, so studies that differ only in those values share compiled code).
    """

    fn: Callable
    dims: tuple[str, ...] | None = eqx.field(static=True, default=None)

    def __call__(self, traj: Trajectory) -> jax.Array:
        return jnp.asarray(self.fn(traj), jnp.float64)


# The built-in outputs are module-level functions (or modules), not closures, so
# that two calls of a factory give equal `Output`s: studies built from fresh
# `peak_elastic_force()` etc. then share compiled code.


def _states(traj: Trajectory) -> jax.Array:
    return traj.y


def _object_states(traj: Trajectory) -> jax.Array:
    return traj.y[:, 0]


def trajectory() -> Output:
    """The full $Y(t)$ on the study's output times, shape `(time, body, coordinate)`
    (choose a coarse `ts` to keep it small)."""
    return Output(_states, ("time", "body", "coordinate"))


def object_pose() -> Output:
    """The object's coordinates $Y_0(t)$, shape `(time, coordinate)`."""
    return Output(_object_states, ("time", "coordinate"))


class _FinalPoseError(eqx.Module):
    reference: jax.Array | None

    def __call__(self, traj: Trajectory) -> jax.Array:
        target = traj.y[0, 0] if self.reference is None else self.reference
        return traj.y[-1, 0] - target


def final_pose_error(reference=None) -> Output:
    """$Y_0(t_1) - Y_{ref}$, the object's final pose error (three positions [m] and
    three Euler angles [rad]), shape `(coordinate,)`. `reference` defaults to the
    object's initial pose."""
    ref = None if reference is None else jnp.asarray(reference, jnp.float64)
    return Output(_FinalPoseError(ref), ("coordinate",))


def _link_force_magnitude(traj: Trajectory) -> jax.Array:
    """$|F_{ij}(t)|$, the norm of the force part of each connection's wrench on its
    first body, shape `(time, connection)`."""
    model = _require_mobile(traj.model, "elastic forces")
    wrench = jax.vmap(model.connection_wrench)(traj.y)
    return _norm(wrench[..., :3])


def _peak_link_force_magnitude(traj: Trajectory) -> jax.Array:
    return jnp.max(_link_force_magnitude(traj), axis=0)


def elastic_force() -> Output:
    """$|F_{ij}(t)|$ [N], the magnitude of each connection's elastic force on its
    first body (the grasp load), shape `(time, connection)`.

    One number per connection: the norm of the three force components of
    `Trajectory.elastic_wrench()`. Not to be confused with the per-body generalized
    elastic force $\\partial\\Pi/\\partial Y$ of `Trajectory.elastic_forces()` (the
    variable `elastic_force` of `trajectory_to_xarray`), shape `(time, body,
    coordinate)`."""
    return Output(_link_force_magnitude, ("time", "connection"))


def peak_elastic_force() -> Output:
    """$\\max_t |F_{ij}(t)|$ [N] per connection, the peak of `elastic_force`'s
    magnitude, shape `(connection,)`."""
    return Output(_peak_link_force_magnitude, ("connection",))


def _peak_link_force_rise(traj: Trajectory) -> jax.Array:
    force = _link_force_magnitude(traj)
    return jnp.max(force, axis=0) - force[0]


def peak_elastic_force_rise() -> Output:
    """$\\max_t |F_{ij}(t)| - |F_{ij}(t_0)|$ [N] per connection: how far the
    grasp load rises above its value at the start, shape `(connection,)`. For
    samples that start at rest (`Study(initial="equilibrium")`), the load the
    motion adds to the static one; zero when the load never rises above it."""
    return Output(_peak_link_force_rise, ("connection",))


def _peak_deflection(traj: Trajectory) -> jax.Array:
    model = _require_mobile(traj.model, "link deflections")
    d = traj.y[:, model.pairs[:, 0], :3] - traj.y[:, model.pairs[:, 1], :3]
    per_link = jax.vmap(deflection, in_axes=(0, 0))
    delta = jax.vmap(per_link, in_axes=(0, None))(d, model.rest_length)
    return jnp.max(_norm(delta), axis=0)


def max_deflection() -> Output:
    """$\\max_t |\\delta_{ij}(t)|$ [m], the largest link deflection
    $\\delta = (1 - \\rho_0/|r_i - r_j|)(r_i - r_j)$ per connection, shape
    `(connection,)`."""
    return Output(_peak_deflection, ("connection",))


def _norm(v):
    """$|v|$ over the last axis, with a finite derivative at $v = 0$ (the unloaded
    state), where `sqrt` alone would give NaN tangents."""
    sq = jnp.sum(v**2, axis=-1)
    zero = sq == 0  # NaN (a sample after its early stop) stays NaN
    return jnp.where(zero, 0.0, jnp.sqrt(jnp.where(zero, 1.0, sq)))


def _require_mobile(model, what: str) -> MobileModel:
    if not isinstance(model, MobileModel):
        raise ValueError(
            f"{what} are defined per connection and need a MobileModel, got "
            f"{type(model).__name__}"
        )
    return model
