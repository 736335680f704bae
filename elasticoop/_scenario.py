"""A complete simulation set-up as one value: `Scenario` (scenario files are read
into one by `elasticoop.load_scenario`)."""

import dataclasses
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float

from ._custom_types import ArrayInput, State, Times, Validated
from ._forces import AbstractForce
from ._models import AbstractElasticModel
from ._motion import PrescribedMotion, SplineMotion
from ._naming import default_body_names
from ._options import SimulationOptions, resolve_options
from ._trajectory import Trajectory
from ._validation import as_float_array, check_times


@dataclasses.dataclass(frozen=True)
class PrescribedSpec:
    """Prescribed coordinates of a scenario, as plain data.

    - `mask`: bool array `(bodies, 6)`, True where the coordinate is prescribed.
    - `ts`: sample times [s] of the motion, or `None` for "hold" (every prescribed
      coordinate keeps its initial value).
    - `values`: `(bodies, 6)` held values (hold), or `(len(ts), bodies, 6)` samples
      (SI units, angles in radians); coordinates the CSV does not list are held at
      their initial value, and entries outside `mask` carry the initial state.
    """

    mask: Bool[np.ndarray, "bodies 6"]
    ts: Float[np.ndarray, " times"] | None
    values: Float[np.ndarray, "bodies 6"] | Float[np.ndarray, "times bodies 6"]

    @property
    def hold(self) -> bool:
        return self.ts is None

    def motion(self, ts: Float[Array | np.ndarray, " times"]) -> PrescribedMotion:
        """The `PrescribedMotion` for a run over `ts`: a natural cubic spline
        through the samples, or the held values (a constant spline over `ts`)."""
        if self.ts is None:  # hold
            span = np.array([float(ts[0]), float(ts[-1])])
            held = np.asarray(self.values, dtype=float)
            return PrescribedMotion(
                self.mask, SplineMotion(span, np.stack([held, held]))
            )
        return PrescribedMotion(self.mask, SplineMotion(self.ts, self.values))


@dataclasses.dataclass(frozen=True)
class IdentifySpec:
    """What `elasticoop identify` fits, from a scenario's `[identify]` table.

    - `fit`: the quantities fitted, of `"stiffness"`, `"damping"` (per connection
      and axis), `"mass"` and `"inertia"` (per body).
    - `connections`, `axes`: the connections (by name) and axes (coordinate names)
      whose stiffness and damping are fitted; `None`: all.
    - `bodies`: the bodies (by name) whose mass and inertia are fitted; `None`: all.
    - `max_iterations`, `method`, `init`: passed to `identify` (as
      `max_iterations`, `method`, `init`).
    - `initial`: how each experiment's initial state is set (`identify`'s
      `initial`); `None`: `"equilibrium"` for a scenario that starts from its
      equilibrium, `"frozen"` otherwise.
    - `feedforward`: a pose tracking's feedforward during the fit (`identify`'s
      `feedforward`): `"frozen"` numbers, `"rest"` (holding the rest state), or
      `"auto"` (the command line's rule: frozen, and rest where frozen numbers
      derived with `feedforward = "hold"` leave a misfit that rest removes).
    """

    fit: tuple[str, ...] = ("stiffness", "damping")
    connections: tuple[str, ...] | None = None
    axes: tuple[str, ...] | None = None
    bodies: tuple[str, ...] | None = None
    max_iterations: int = 100
    method: str = "levenberg-marquardt"
    init: str = "equation_error"
    initial: str | None = None
    feedforward: str = "auto"


class Scenario(eqx.Module):
    """A complete simulation set-up: model, initial state, output times, forces,
    solver settings (`options`, a `SimulationOptions`) and the names of bodies and
    connections.

    `scenario.simulate()` runs it; `elasticoop.load_scenario(path)` reads one from a
    TOML scenario file. `solver`, `rtol`, `atol` and `max_steps` read the fields of
    `options`; passed to the constructor they are deprecated spellings of
    `options=SimulationOptions(...)` (a `DeprecationWarning`).
    """

    name: str = eqx.field(static=True)
    model: AbstractElasticModel
    y_init: State
    ydot_init: State
    ts: Times
    forces: AbstractForce | None
    body_names: tuple[str, ...] = eqx.field(static=True)
    connection_names: tuple[str, ...] = eqx.field(static=True)
    options: SimulationOptions = eqx.field(static=True)
    prescribed: PrescribedSpec | None
    description: str = eqx.field(static=True)
    source: str | None = eqx.field(static=True)
    identify: IdentifySpec | None = eqx.field(static=True)
    # `[initial] from` ("equilibrium": the run starts at rest in the static
    # equilibrium of the model); None: the initial state as given
    initial_from: str | None = eqx.field(static=True)

    def __init__(
        self,
        name: str,
        model: Validated[AbstractElasticModel],
        y_init: Validated[ArrayInput],
        ydot_init: Validated[ArrayInput],
        ts: Validated[ArrayInput],
        forces: AbstractForce | None,
        body_names: tuple[str, ...] = (),
        connection_names: tuple[str, ...] = (),
        solver: str | None = None,
        rtol: float | None = None,
        atol: float | None = None,
        max_steps: int | None = None,
        prescribed: PrescribedSpec | None = None,
        description: str = "",
        source: str | None = None,
        identify: IdentifySpec | None = None,
        initial_from: str | None = None,
        *,
        options: Validated[SimulationOptions | None] = None,
    ):
        if not isinstance(model, AbstractElasticModel):
            raise ValueError(
                f"Scenario.model must be an ImmobileModel or a MobileModel, got "
                f"{type(model).__name__}"
            )
        self.name = name
        self.model = model
        # shapes now, as `simulate` would check them (finiteness where concrete)
        n = model.n_bodies
        self.y_init, self.ydot_init = (
            jnp.asarray(
                as_float_array(value, f"Scenario.{label}", (n, 6), check_traced=False)
            )
            for label, value in (("y_init", y_init), ("ydot_init", ydot_init))
        )
        self.ts = jnp.asarray(check_times(ts, "Scenario.ts"))
        self.forces = forces
        self.body_names = body_names
        self.connection_names = connection_names
        if options is not None and not isinstance(options, SimulationOptions):
            raise ValueError(
                f"Scenario.options must be a SimulationOptions, got "
                f"{type(options).__name__}"
            )
        if options is None:
            options = SimulationOptions(owner="Scenario")
        self.options = resolve_options(
            options,
            "Scenario",
            solver=solver,
            rtol=rtol,
            atol=atol,
            max_steps=max_steps,
        )
        self.prescribed = prescribed
        self.description = description
        self.source = source
        self.identify = identify
        self.initial_from = initial_from

    @property
    def solver(self) -> str:
        """The solver's name (`options.solver_name`)."""
        return self.options.solver_name

    @property
    def rtol(self) -> float:
        """`options.rtol`."""
        return float(self.options.rtol)

    @property
    def atol(self) -> float:
        """`options.atol`."""
        return float(self.options.atol)

    @property
    def max_steps(self) -> int:
        """`options.max_steps`."""
        return int(self.options.max_steps)

    @property
    def names(self) -> tuple[str, ...]:
        """Body names (`body_names`, or object, contact1, ... when not given)."""
        return self.body_names or default_body_names(self.model.n_bodies)

    def simulate(self, **overrides: Any) -> Trajectory:
        """Run `elasticoop.simulate` with this scenario's model, initial state,
        times, forces and `options`; keyword arguments of `simulate` override
        them (`model=`, `y_init=`, `ydot_init=`, `ts=`, `forces=`, `options=`, or
        e.g. `progress_meter=diffrax.TqdmProgressMeter()`). The prescribed motion
        follows the times the run takes."""
        kwargs: dict[str, Any] = dict(
            model=self.model,
            y_init=self.y_init,
            ydot_init=self.ydot_init,
            ts=self.ts,
            forces=self.forces,
            options=self.options,
        )
        kwargs.update(overrides)
        if self.prescribed is not None and "prescribed" not in overrides:
            kwargs["prescribed"] = self.prescribed.motion(kwargs["ts"])
        from ._simulate import simulate  # the engine, imported when a run needs it

        return simulate(**kwargs)
