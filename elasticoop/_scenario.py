"""A complete study set-up (`Scenario`), the pose-tracking manipulators, and the
built-in scenario (loaded from the packaged `scenarios/beam_lift.toml`)."""

import dataclasses
import importlib.resources

import diffrax
import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._analysis import PrescribedMotion, SplineMotion
from ._forces import AbstractForce
from ._models import AbstractElasticModel
from ._simulate import simulate
from ._trajectory import Trajectory

DEFAULT_EXAMPLE = "beam_lift"

# Solver names of scenario files -> diffrax solvers.
SOLVERS = {
    "tsit5": diffrax.Tsit5,
    "dopri5": diffrax.Dopri5,
    "dopri8": diffrax.Dopri8,
    "bosh3": diffrax.Bosh3,
    "heun": diffrax.Heun,
    "kvaerno3": diffrax.Kvaerno3,
    "kvaerno5": diffrax.Kvaerno5,
}


def minimum_jerk(s):
    """$10s^3 - 15s^4 + 6s^5$ on $[0, 1]$, held at 0 and 1 outside."""
    s = jnp.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


class PoseTracking(AbstractForce):
    """Manipulators as PD controllers on the grasp poses plus a weight feedforward.

    Grasp body $i$ is driven towards $Y_{i}^{ref}(t) = Y_{i}(0) + h\\,s(t/T)\\,e_z$
    ($s$ the minimum-jerk profile):
    $F_i = F^{ff} + K_p (Y_i^{ref} - Y_i) + K_d (\\dot Y_i^{ref} - \\dot Y_i)$,
    gains per coordinate (translations [N/m], Euler angles [N m/rad]).
    """

    y_ref: jnp.ndarray  # (m, 6) initial grasp poses
    feedforward: jnp.ndarray  # (m, 6)
    kp: jnp.ndarray  # (6,)
    kd: jnp.ndarray  # (6,)
    height: float
    duration: float

    def __call__(self, t, y, ydot):
        s = minimum_jerk(t / self.duration)
        tau = jnp.clip(t / self.duration, 0.0, 1.0)
        rate = 30.0 * tau**2 * (1.0 - tau) ** 2 / self.duration
        lift = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        ref = self.y_ref + self.height * s * lift
        ref_rate = self.height * rate * lift
        grasps, rates = y[1:], ydot[1:]
        return (
            self.feedforward + self.kp * (ref - grasps) + self.kd * (ref_rate - rates)
        )


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

    mask: np.ndarray
    ts: np.ndarray | None
    values: np.ndarray

    @property
    def hold(self) -> bool:
        return self.ts is None

    def motion(self, ts) -> PrescribedMotion:
        """The `PrescribedMotion` for a run over `ts`: a natural cubic spline
        through the samples, or the held values (a constant spline over `ts`)."""
        if self.hold:
            span = np.array([float(ts[0]), float(ts[-1])])
            held = np.asarray(self.values, dtype=float)
            return PrescribedMotion(
                self.mask, SplineMotion(span, np.stack([held, held]))
            )
        return PrescribedMotion(self.mask, SplineMotion(self.ts, self.values))


class Scenario(eqx.Module):
    """A complete simulation set-up: model, initial state, output times, forces,
    solver settings and the names of bodies and connections.

    `scenario.simulate()` runs it; `elasticoop.load_scenario(path)` reads one from a
    TOML scenario file.
    """

    name: str = eqx.field(static=True)
    model: AbstractElasticModel
    y_init: jnp.ndarray
    ydot_init: jnp.ndarray
    ts: jnp.ndarray
    forces: AbstractForce | None
    body_names: tuple[str, ...] = eqx.field(static=True, default=())
    connection_names: tuple[str, ...] = eqx.field(static=True, default=())
    solver: str = eqx.field(static=True, default="tsit5")
    rtol: float = eqx.field(static=True, default=1e-8)
    atol: float = eqx.field(static=True, default=1e-10)
    max_steps: int = eqx.field(static=True, default=100_000)
    prescribed: PrescribedSpec | None = None
    description: str = eqx.field(static=True, default="")
    source: str | None = eqx.field(static=True, default=None)

    def __check_init__(self):
        if self.solver not in SOLVERS:
            raise ValueError(
                f"Scenario.solver must be one of {sorted(SOLVERS)}, got {self.solver!r}"
            )

    @property
    def names(self) -> tuple[str, ...]:
        """Body names (`body_names`, or object, contact1, ... when not given)."""
        return self.body_names or default_body_names(self.model.n_bodies)

    def simulate(self, **overrides) -> Trajectory:
        """Run `elasticoop.simulate` with this scenario's model, initial state,
        times, forces, solver and tolerances; keyword arguments override them
        (e.g. `progress_meter=diffrax.TqdmProgressMeter()` where supported)."""
        kwargs = dict(
            forces=self.forces,
            solver=SOLVERS[self.solver](),
            rtol=self.rtol,
            atol=self.atol,
            max_steps=self.max_steps,
        )
        if self.prescribed is not None:
            kwargs["prescribed"] = self.prescribed.motion(self.ts)
        kwargs.update(overrides)
        return simulate(self.model, self.y_init, self.ydot_init, self.ts, **kwargs)


def default_body_names(n_bodies: int) -> tuple[str, ...]:
    return ("object",) + tuple(f"contact{i}" for i in range(1, n_bodies))


def example_files() -> dict[str, object]:
    """The example scenarios shipped with elasticoop: name -> TOML file (a
    `importlib.resources` traversable)."""
    folder = importlib.resources.files("elasticoop") / "scenarios"
    return {
        f.name[: -len(".toml")]: f
        for f in sorted(folder.iterdir(), key=lambda f: f.name)
        if f.name.endswith(".toml")
    }


def load_example(name: str) -> Scenario:
    """Load a packaged example scenario by name (see `example_files()`)."""
    from ._config import load_scenario

    files = example_files()
    if name not in files:
        raise ValueError(f"no example scenario {name!r}; examples: {sorted(files)}")
    with importlib.resources.as_file(files[name]) as path:
        return load_scenario(path)


def default_scenario(n_output: int = 301) -> Scenario:
    """Two manipulators lift a 1 m, 2 kg beam by 0.2 m in 2 s through elastic grasps
    at its ends (3 bodies, 2 connections, ZXZ angles at $\\theta = \\pi/2$, so the
    body x axis is the beam's axis), then hold it for 1 s; read from the packaged
    `scenarios/beam_lift.toml`. `n_output` evenly spaced output samples."""
    scenario = load_example(DEFAULT_EXAMPLE)
    if n_output != scenario.ts.shape[0]:
        ts = jnp.linspace(scenario.ts[0], scenario.ts[-1], n_output)
        scenario = eqx.tree_at(lambda s: s.ts, scenario, ts)
    return scenario
