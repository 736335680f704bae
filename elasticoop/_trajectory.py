"""The result of `simulate` and the quantities derived from it."""

import functools
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any, TypeVar, cast

import equinox as eqx
import jax
import jax.numpy as jnp
from jaxtyping import Array, Bool, Float, Int

from ._custom_types import Scalar, StateSeries, Times
from ._lagrange import elastic_forces
from ._models import AbstractElasticModel, MobileModel
from ._status import Status, status_message

if TYPE_CHECKING:
    import xarray


_Method = TypeVar("_Method", bound=Callable[..., Any])


def _per_trajectory(method: _Method) -> _Method:
    """`method` of one trajectory, mapped over the batch of a batched one."""

    @functools.wraps(method)
    def each(self: "Trajectory") -> Any:
        if jnp.ndim(self.ts) == 1:
            return method(self)
        return jax.vmap(method)(self)

    return cast(_Method, each)


class Trajectory(eqx.Module):
    """A simulated motion of the elastic system.

    **Fields:**

    - `ts`: times, shape `(times,)` [s].
    - `y`, `ydot`: $Y(t)$ and $\\dot Y(t)$, shape `(times, bodies, 6)` (positions [m],
      angles [rad] and their rates).
    - `work`: work done by the applied forces since `ts[0]`,
      $\\int F\\cdot\\dot Y\\,dt$ [J], shape `(times,)`.
    - `dissipated`: energy dissipated since `ts[0]`, $\\int 2R\\,dt$ [J].
    - `model`: the model that was simulated.
    - `status`: a `Status` code (0 = success). After an early stop (gimbal lock, a
      collapsed link, NaN or inf, the end of the force samples, a solver failure)
      the samples after `event_time` are NaN.
    - `event_time`: the time the run stopped early ($t_1$ when it did not).
    - `event_index`: the body (gimbal lock; NaN or inf in its initial state or
      force) or connection (collapsed link) at fault, -1 otherwise.
    - `reaction`: with prescribed coordinates, the generalized forces that realise
      the prescribed motion, shape `(times, bodies, 6)` (zero on the free
      coordinates); `None` otherwise.
    - `n_steps`: the number of solver steps taken, accepted and rejected (what
      `max_steps` bounds).

    Under `jax.vmap` every field gains a leading batch axis: `traj[i]` is the
    trajectory of element `i`, and the energy and force methods below return
    one series per element, with the batch axis first.
    """

    ts: Times
    y: StateSeries
    ydot: StateSeries
    work: Times
    dissipated: Times
    model: AbstractElasticModel
    status: Int[Array, ""]
    event_time: Scalar
    event_index: Int[Array, ""]
    reaction: StateSeries | None = None
    n_steps: Int[Array, ""] | None = None

    def to_xarray(
        self,
        body_names: Iterable[str] | None = None,
        connection_names: Iterable[str] | None = None,
        attrs: dict[str, Any] | None = None,
        forces: Any = None,
    ) -> "xarray.Dataset":
        """The trajectory as an `xarray.Dataset` (dims `time`, `body`, `coordinate`),
        with units, the model's parameters as data variables and its kind,
        convention, gravity and status as attributes: `trajectory_to_xarray(self,
        ...)`, whose arguments these are (`forces`: the run's applied forces, in
        any form `simulate` takes, for the variable `applied_force`)."""
        # The one import against the layers (results -> files): a convenience
        # method users expect on the result; the converter lives in `_io`.
        from ._io.xarray import trajectory_to_xarray

        return trajectory_to_xarray(
            self,
            body_names=body_names,
            connection_names=connection_names,
            attrs=attrs,
            forces=forces,
        )

    @property
    def succeeded(self) -> Bool[Array, "*batch"]:
        return self.status == Status.SUCCESS

    def __getitem__(self, index: Any) -> "Trajectory":
        """The trajectories `index` of a batch (`jax.vmap` gives every field a
        leading axis): `traj[0]`, `traj[2:5]`."""
        if jnp.ndim(self.ts) != 2:
            raise TypeError(
                "a single trajectory has no batch axis to index (only the results "
                "of jax.vmap(simulate) do); index its fields instead, e.g. traj.y[k]"
            )
        return jax.tree.map(lambda x: x[index], self)

    def _over_time(self, fn, *fields):
        return _map_over_time(fn, *fields)

    @_per_trajectory
    def kinetic_energy(self) -> Times:
        """$T(t)$ [J]."""
        return self._over_time(self.model.kinetic_energy, self.y, self.ydot)

    @_per_trajectory
    def elastic_energy(self) -> Times:
        """$\\Pi(t)$ [J]."""
        return self._over_time(self.model.potential, self.y)

    @_per_trajectory
    def gravity_energy(self) -> Times:
        """$\\sum_i m_i g z_i(t)$ [J]."""
        return self._over_time(self.model.gravity_potential, self.y)

    @_per_trajectory
    def total_energy(self) -> Times:
        """$E = T + \\Pi + \\sum_i m_i g z_i$ [J]."""
        return self._over_time(self.model.total_energy, self.y, self.ydot)

    @_per_trajectory
    def dissipated_power(self) -> Times:
        """$2R(Y, \\dot Y)$ [W], the power lost in the dampers."""
        return 2 * self._over_time(self.model.dissipation, self.y, self.ydot)

    @_per_trajectory
    def energy_residual(self) -> Times:
        """$E(t) - E(t_0) - W_F(t) + E_{diss}(t)$: zero up to the solver's error by
        the balance $\\dot E = F\\cdot\\dot Y - 2R$."""
        energy = self.total_energy()
        return energy - energy[0] - self.work + self.dissipated

    @_per_trajectory
    def elastic_forces(self) -> StateSeries:
        """$\\partial\\Pi/\\partial Y$ per body [N, N m], shape `(times, bodies, 6)`."""
        return self._over_time(lambda y: elastic_forces(self.model, y), self.y)

    @_per_trajectory
    def elastic_wrench(self) -> Float[Array, "times connections 6"]:
        """Generalized elastic force of each connection on its first body,
        $-\\partial\\Pi_{ij}/\\partial Y_i$, shape `(times, connections, 6)`
        (`MobileModel` only; for an `ImmobileModel` see `elastic_forces`)."""
        if not isinstance(self.model, MobileModel):
            raise ValueError(
                "elastic_wrench needs a MobileModel (an ImmobileModel has no "
                "connections); use Trajectory.elastic_forces() for dPi/dY per body"
            )
        return self._over_time(self.model.connection_wrench, self.y)

    def grasp_loads(
        self,
    ) -> tuple[list[tuple[int, int]], Float[Array, "times grasps 6"]]:
        """The elastic load at each grasp: `(pairs, wrench)` with `wrench` of shape
        `(times, grasps, 6)`. Per connection $(i, j)$ for a `MobileModel`
        (`elastic_wrench`, on body $i$), per contact body $k$ for an
        `ImmobileModel` ($-\\partial\\Pi/\\partial Y_k$, pair $(0, k)$)."""
        if isinstance(self.model, MobileModel):
            pairs = [(int(i), int(j)) for i, j in jnp.asarray(self.model.pairs)]
            return pairs, self.elastic_wrench()
        pairs = [(0, k) for k in range(1, self.model.n_bodies)]
        return pairs, -self.elastic_forces()[..., 1:, :]

    def message(self) -> str:
        """A sentence describing `status` (for a single, un-batched trajectory)."""
        if jnp.ndim(self.ts) != 1:
            raise ValueError(
                "message() describes one trajectory, and this is a batch (from "
                "jax.vmap); take one with traj[i]"
            )
        return status_message(self)


@eqx.filter_jit
def _map_over_time(fn, *fields):
    # `fn` is a bound method of the model (an equinox pytree): compiled once per
    # method and model structure.
    return jax.vmap(fn)(*fields)


class SimulationError(RuntimeError):
    """A simulation stopped early: gimbal lock, a collapsed link or solver failure.

    `.trajectory` holds the partial result (`status`, `event_time`, `event_index`).
    """

    def __init__(self, message: str, trajectory: Trajectory):
        super().__init__(message)
        self.trajectory = trajectory
