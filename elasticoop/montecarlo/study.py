"""`Study`: the specification of a Monte Carlo study (what varies, what is kept),
and what one sample of it computes."""

import copy
import hashlib
import json
import warnings
from collections.abc import Callable, Mapping, Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._analysis import closed_loop_rest, closed_loop_stiffness
from .._forces import check_force, force_admissible
from .._models import AbstractElasticModel, MobileModel
from .._models.base import RANK_RTOL
from .._naming import (
    body_names as checked_body_names,
    connection_names,
    coordinate_names,
)
from .._options import SimulationOptions
from .._simulate import simulate
from .._validation import as_float_array, check_times
from .fingerprint import Digest, abstract
from .outputs import Output
from .parameters import _RESERVED, Inputs, Parameter
from .sampling import QMC_DESIGNS, check_design, design_row_template, draw

SAMPLING = ("random", "lhs", *QMC_DESIGNS)
# What each sample starts from: its own rest state, or the initial state given.
INITIAL = ("equilibrium", "given")

# Status of a sample whose drawn parameters are not finite (it is not simulated).
INVALID_SAMPLE = -1


def key_data(key) -> np.ndarray:
    """The raw `uint32` data of a `jax.random` key (a seed `int` is turned into
    `jax.random.key(seed)` first)."""
    if isinstance(key, int | np.integer) and not isinstance(key, bool):
        key = jax.random.key(int(key))
    key = jnp.asarray(key)
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    data = np.asarray(key)
    if data.dtype != np.uint32 or data.shape != (2,):
        raise ValueError(
            f"key must be an int seed or a single jax.random key, got {key!r}"
        )
    return data


class Study(eqx.Module):
    """A Monte Carlo study of the elastic system.

    Sample $s$ draws every parameter from its distribution with randomness that
    depends only on `(key, s)` (`jax.random.fold_in`), so results do not depend on
    how the samples are split into chunks or over devices and processes.

    A `Study` is a pytree: its arrays (the model, initial state, forces, times, key
    and the distributions' parameters) are leaves, its structure (parameters and
    outputs, sampling, `n_samples`, solver options, shapes) is static. Studies that
    differ only in those arrays share compiled code, and so do studies that differ
    in `n_samples` too (run in chunks of the same size), but for Latin hypercube
    sampling.

    **Arguments:**

    - `model`, `y_init`, `ydot_init`, `ts`, `forces`: the nominal inputs of
      `simulate` (`ts` are the output times of every sample: keep it coarse when
      whole trajectories are kept).
    - `parameters`: a sequence of `Parameter` (the uncertain leaves).
    - `outputs`: a mapping name -> `Output` (or a callable of the `Trajectory`).
    - `n_samples`: number of samples.
    - `key`: a `jax.random` key or an integer seed.
    - `sampling`: `"random"` (independent draws) or `"lhs"` (Latin hypercube: each
      scalar parameter's range is cut into `n_samples` strata of equal probability,
      each hit once), or a quasi-Monte Carlo design of `sampling.QMC_DESIGNS`
      (`"sobol"` points, the `"saltelli"` and `"saltelli-second-order"` designs
      of Sobol' indices, `"morris"` trajectories; see `sampling`).
    - `initial`: what each sample starts from.
      `"given"` (the default): `y_init` and `ydot_init`, the same for every sample
      (unless they are parameters).
      `"equilibrium"`: each sample starts at rest in its own closed loop: every
      coordinate (the object's and the contact bodies') solves
      $\\partial\\Pi/\\partial Y = G + F(t_0, Y, 0)$ with the sample's
      parameters and its force law $F$ at rest at the first time
      (`closed_loop_rest`). The force law is a fact of the experiment: a
      feedforward computed from the nominal system (a scenario's
      `feedforward = "hold"`) stays the number it is, and a sample whose
      parameters differ settles where its controller's forces balance its own
      grasps' reactions (the grasps a little off their commanded poses), so it is
      at rest in the simulation from its first step: its outputs measure what
      the experiment does (a lift), not a start-up transient. The force law must
      hold the contact bodies (e.g. `PoseTracking` with positive gains; with
      constant forces there is no isolated rest state: a `ValueError`).
      `y_init` is the start of the solver (best: the nominal rest state), and
      neither it nor `ydot_init` (which must be zero) may be a parameter. A
      sample without a rest state (the solver does not converge) fails with
      `Status.NONFINITE`. Use it whenever the study varies what the start
      depends on (masses, stiffnesses, rest lengths, gravity, gains): with
      `"given"`, a sample other than the nominal one starts away from its rest,
      and its outputs include that start-up transient.
    - `options`: a `SimulationOptions` (solver, tolerances, step budget and
      singularity thresholds of every sample; default `SimulationOptions()`,
      Dopri8 at rtol 1e-9, atol 1e-11, as `simulate`'s).
    - `solver`, `rtol`, `atol`, `max_steps`: deprecated spellings of `options`
      (a `DeprecationWarning`; they cannot be combined with it).
    - `body_names`, `connection_names`: labels of the `body` and `connection` axes
      in the results (default `object, contact1, ...` and `<body_i>-<body_j>`);
      they name, and do not change, the samples.
    """

    inputs: Inputs
    ts: np.ndarray | jax.Array
    key_data: np.ndarray
    parameters: tuple[Parameter, ...]
    _output_fns: tuple[Output, ...]
    _output_names: tuple[str, ...] = eqx.field(static=True)
    n_samples: int = eqx.field(static=True)
    sampling: str = eqx.field(static=True)
    initial: str = eqx.field(static=True)
    # where each sample's rest state is sought from: the nominal closed-loop rest
    # state
    rest_guess: jax.Array | None
    options: SimulationOptions = eqx.field(static=True)
    _leaf_shapes: tuple[tuple[str, tuple[int, ...]], ...] = eqx.field(static=True)
    # (name, shape, dtype) of every entry of one sample's record
    _record: tuple[tuple[str, tuple[int, ...], np.dtype], ...] = eqx.field(static=True)
    body_names: tuple[str, ...] = eqx.field(static=True)
    connection_names: tuple[str, ...] | None = eqx.field(static=True)

    def __init__(
        self,
        model: AbstractElasticModel,
        y_init,
        ydot_init,
        ts,
        parameters: Sequence[Parameter],
        outputs: Mapping[str, Output | Callable],
        n_samples: int,
        key=0,
        forces=None,
        sampling: str = "random",
        solver: diffrax.AbstractSolver | str | None = None,
        rtol: float | None = None,
        atol: float | None = None,
        max_steps: int | None = None,
        body_names=None,
        connection_names=None,
        *,
        initial: str = "given",
        options: SimulationOptions | None = None,
    ):
        if not isinstance(model, AbstractElasticModel):
            raise ValueError(
                f"Study.model must be an ImmobileModel or MobileModel, got "
                f"{type(model).__name__}"
            )
        n = model.n_bodies
        self.body_names = checked_body_names(body_names, n)
        self.connection_names = _connection_names(
            model, connection_names, self.body_names
        )
        y_init = jnp.asarray(as_float_array(y_init, "Study.y_init", (n, 6)))
        ydot_init = jnp.asarray(as_float_array(ydot_init, "Study.ydot_init", (n, 6)))
        ts = check_times(ts, "Study.ts")
        force = check_force(forces, y_init, ydot_init, ts, "Study.")
        self.inputs = Inputs(model, y_init, ydot_init, force)
        self.ts = ts

        if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer):
            raise ValueError(f"Study.n_samples must be an integer, got {n_samples!r}")
        if n_samples < 1:
            raise ValueError(f"Study.n_samples must be >= 1, got {n_samples}")
        self.n_samples = int(n_samples)
        self.key_data = key_data(key)
        if sampling not in SAMPLING:
            raise ValueError(
                f"Study.sampling must be one of {SAMPLING}, got {sampling!r}"
            )
        self.sampling = sampling
        self.options = _options(options, solver, rtol, atol, max_steps)
        if initial not in INITIAL:
            raise ValueError(f"Study.initial must be one of {INITIAL}, got {initial!r}")
        self.initial = initial
        self.rest_guess = None

        self.parameters = tuple(parameters)
        self._leaf_shapes = self._check_parameters()
        check_design(self)
        if not any(p.target == "y_init" for p in self.parameters):
            # every sample starts from the nominal state: it must be regular
            model.rotation.check_regular(
                y_init[:, 3:],
                self.options.gimbal_tol,
                "Study.y_init",
                self.body_names,
            )
        if initial == "equilibrium":
            self.rest_guess = self._nominal_rest_state()
        self._output_names, self._output_fns = self._check_outputs(outputs)
        self._record = self._check_record()

    def _nominal_rest_state(self) -> jax.Array:
        """The rest state of the nominal inputs (the start of every sample's
        search); a `ValueError` when there is none, or a parameter varies the
        initial rates."""
        if np.any(np.asarray(self.inputs.ydot_init) != 0):
            raise ValueError(
                "Study.ydot_init must be zero with initial='equilibrium' (every "
                "sample starts at rest)"
            )
        for p in self.parameters:
            if p.target in ("y_init", "ydot_init"):
                raise ValueError(
                    f"Parameter {p.name!r} varies {p.target}, but with "
                    f"initial='equilibrium' every sample starts at rest, its "
                    f"initial state solved for"
                )
        t0 = jnp.asarray(self.ts[0])
        singular = False
        y = _rest(self.inputs, t0, self.inputs.y_init)
        if np.all(np.isfinite(np.asarray(y))):
            k = closed_loop_stiffness(self.inputs.model, y, self.inputs.forces, t0)
            sv = np.linalg.svd(np.asarray(k), compute_uv=False)
            singular = bool(sv.min() <= RANK_RTOL * sv.max())
        if not np.all(np.isfinite(np.asarray(y))) or singular:
            raise ValueError(
                "Study(initial='equilibrium'): the nominal system has no "
                "closed-loop rest state (every coordinate free under the force law "
                "at rest at the first time: "
                + (
                    "the closed-loop stiffness K - dF/dY is singular, the force "
                    "law does not hold the contact bodies, e.g. constant forces"
                    if np.all(np.isfinite(np.asarray(y)))
                    else "the solver did not converge from y_init"
                )
                + "); use a force law that holds the grasps (pose_tracking), start "
                "y_init nearer to the rest state, or use initial='given'"
            )
        return y

    def _check_parameters(self) -> tuple:
        shapes = {}
        labels = self._labels()
        selected: dict[int, str] = {}  # leaf position in `inputs` -> parameter
        for k, p in enumerate(self.parameters):
            if not isinstance(p, Parameter):
                raise ValueError(
                    f"Study.parameters[{k}] must be a Parameter, got {p!r}"
                )
            if p.name in shapes:
                raise ValueError(f"Study.parameters: name {p.name!r} is used twice")
            try:
                leaf = p.nominal(self.inputs)
            except (AttributeError, TypeError, IndexError) as err:
                raise ValueError(
                    f"Parameter {p.name!r}: where does not select a leaf of the "
                    f"{p.target}: {err}"
                ) from None
            marker = _Marker()
            try:
                marked = eqx.tree_at(p._select, self.inputs, marker)
            except (TypeError, ValueError):
                raise ValueError(
                    f"Parameter {p.name!r}: where must select a whole leaf "
                    f"(equinox.tree_at-style, e.g. lambda m: m.bodies.mass), not an "
                    f"expression of it such as an indexed entry"
                ) from None
            position = next(
                i for i, x in enumerate(jax.tree.leaves(marked)) if x is marker
            )
            if position in selected:
                raise ValueError(
                    f"Parameter {p.name!r} selects the same leaf of the {p.target} "
                    f"as parameter {selected[position]!r}: vary each leaf in one "
                    f"parameter (their draws would compose, and the values recorded "
                    f"would not be those simulated)"
                )
            selected[position] = p.name
            if not (
                isinstance(leaf, jax.Array | np.ndarray | np.generic)
                and jnp.issubdtype(leaf.dtype, jnp.floating)
            ):
                raise ValueError(
                    f"Parameter {p.name!r}: where must select a float array, got "
                    f"{leaf!r}"
                )
            shape = tuple(leaf.shape)
            try:
                drawn = jax.eval_shape(
                    lambda key, d=p.distribution, s=shape: d.sample(key, s),
                    jax.random.key(0),
                )
            except (ValueError, TypeError) as err:
                raise ValueError(
                    f"Parameter {p.name!r}: the distribution does not fit the leaf's "
                    f"shape {shape}: {err}"
                ) from None
            if drawn.shape != shape:
                raise ValueError(
                    f"Parameter {p.name!r}: the distribution's parameters have shape "
                    f"{drawn.shape}, which does not broadcast to the leaf's shape "
                    f"{shape}"
                )
            if self.sampling != "random" and not p.distribution.supports_ppf:
                raise ValueError(
                    f"Parameter {p.name!r}: {type(p.distribution).__name__} has no "
                    f"inverse CDF, so sampling={self.sampling!r} is not possible; "
                    f"give it a ppf or use sampling='random'"
                )
            dims = p.leaf_dims(len(shape))
            _check_labelled(f"Parameter {p.name!r}", dims, shape, labels)
            shapes[p.name] = shape
        return tuple(shapes.items())

    def _check_outputs(self, outputs) -> tuple[tuple[str, ...], tuple[Output, ...]]:
        if not isinstance(outputs, Mapping) or not outputs:
            raise ValueError(
                f"Study.outputs must be a non-empty mapping name -> Output, got "
                f"{outputs!r}"
            )
        names, fns = [], []
        for name, out in outputs.items():
            if not isinstance(name, str) or not name.isidentifier():
                raise ValueError(
                    f"Study.outputs: name must be an identifier, got {name!r}"
                )
            if name in _RESERVED or name in self.leaf_shapes:
                raise ValueError(
                    f"Study.outputs: name {name!r} clashes with a reserved or "
                    f"parameter name"
                )
            if not isinstance(out, Output):
                if not callable(out):
                    raise ValueError(
                        f"Study.outputs[{name!r}] must be an Output or a callable of "
                        f"the Trajectory, got {out!r}"
                    )
                out = Output(out)
            names.append(name)
            fns.append(out)
        return tuple(names), tuple(fns)

    def _check_record(self) -> tuple:
        """Shapes and dtypes of one sample's record, checked against the outputs'
        axis names. Traced once per structure: `_record_shapes` is jitted, so a
        study like an earlier one but for its arrays reuses that trace."""
        row = design_row_template(self)
        strata = jnp.zeros(row.shape, row.dtype)
        self._record = ()  # placeholder: the study is a complete pytree from here
        template = eqx.filter_eval_shape(_record_shapes, self, jnp.int64(0), strata)
        labels = self._labels()
        for name, out in self.outputs.items():
            shape = template[name].shape
            if out.dims is not None:
                if len(out.dims) != len(shape):
                    raise ValueError(
                        f"Study.outputs[{name!r}] has dims {out.dims} but returns "
                        f"shape {shape}"
                    )
                _check_labelled(f"Study.outputs[{name!r}]", out.dims, shape, labels)
        return tuple(
            (name, tuple(x.shape), np.dtype(x.dtype)) for name, x in template.items()
        )

    def _record_template(self) -> dict[str, jax.ShapeDtypeStruct]:
        """Shapes and dtypes of one sample's record."""
        return {
            name: jax.ShapeDtypeStruct(shape, dtype)
            for name, shape, dtype in self._record
        }

    def _program_view(self) -> "Study":
        """This study as its compiled programs take it (`run_study`'s batch and
        rest states, `local_sensitivities`' derivatives). Of the static fields,
        `n_samples` is read inside them only by Latin hypercube sampling (the
        strata's width); for any other sampling it is set to 1 in a copy, so that
        a study extended to more samples, or another of the same structure with
        another number of samples, reuses the compiled programs instead of
        compiling them again."""
        if self.sampling == "lhs":
            return self
        view = copy.copy(self)
        # (a static field of a frozen Module, set on a fresh copy of it)
        object.__setattr__(view, "n_samples", 1)
        return view

    def _labels(self) -> dict[str, list]:
        """Labels of the named axes shared with the trajectory export: `time`,
        `body`, `coordinate` and (`MobileModel`) `connection`."""
        model = self.inputs.model
        labels = {
            "time": np.asarray(self.ts).tolist(),
            "body": list(self.body_names),
            "coordinate": list(coordinate_names(model.convention)),
        }
        if self.connection_names is not None:
            labels["connection"] = list(self.connection_names)
        return labels

    @property
    def outputs(self) -> dict[str, Output]:
        """The outputs, name -> `Output`."""
        return dict(zip(self._output_names, self._output_fns))

    @property
    def leaf_shapes(self) -> dict[str, tuple[int, ...]]:
        """The shape of each parameter's leaf, name -> shape."""
        return dict(self._leaf_shapes)

    @property
    def n_dims(self) -> int:
        """Number of scalar uncertain parameters (the dimension of the design)."""
        return int(sum(np.prod(s, dtype=int) for _, s in self._leaf_shapes))

    @property
    def solver(self) -> diffrax.AbstractSolver:
        """The diffrax solver of every sample."""
        return self.options.diffrax_solver()

    @property
    def rtol(self) -> float:
        return float(self.options.rtol)

    @property
    def atol(self) -> float:
        return float(self.options.atol)

    @property
    def max_steps(self) -> int:
        return int(self.options.max_steps)

    def start(self, inputs: Inputs) -> Inputs:
        """`inputs` with the initial state of the study's rule (`initial`): as
        given, or at rest in the closed loop of their parameters and force law
        (`closed_loop_rest`, every coordinate free, sought from the nominal rest
        state; NaN where the solver does not converge, so the sample fails).
        Traceable and differentiable (the rest state by the implicit function
        theorem)."""
        if self.initial != "equilibrium":
            return inputs
        y_rest = _rest(inputs, jnp.asarray(self.ts[0]), self.rest_guess)
        return eqx.tree_at(
            lambda i: (i.y_init, i.ydot_init),
            inputs,
            (y_rest, jnp.zeros_like(y_rest)),
        )

    def simulate(self, inputs: Inputs, **overrides):
        """`simulate` of one sample's `inputs` with the study's times, solver and
        tolerances (never raising: failures are reported in `Trajectory.status`)."""
        kwargs = self.options.kwargs() | dict(forces=inputs.forces, throw=False)
        return simulate(
            inputs.model,
            inputs.y_init,
            inputs.ydot_init,
            self.ts,
            **(kwargs | overrides),
        )

    def describe(self) -> dict:
        """A JSON-able description of the study (recorded in the store's manifest)."""
        return {
            "n_samples": self.n_samples,
            "key": np.asarray(self.key_data).tolist(),
            "sampling": self.sampling,
            "initial": self.initial,
            "ts": np.asarray(self.ts).tolist(),
            "solver": self.options.solver_name,
            "rtol": self.rtol,
            "atol": self.atol,
            "max_steps": self.max_steps,
            "model": type(self.inputs.model).__name__,
            "parameters": [
                {
                    "name": p.name,
                    "target": p.target,
                    "relative": p.relative,
                    "shape": list(self.leaf_shapes[p.name]),
                    "distribution": p.distribution.describe(),
                }
                for p in self.parameters
            ],
            "outputs": {
                name: list(out.dims or ()) for name, out in self.outputs.items()
            },
            "inputs_sha256": _inputs_hash(self.inputs),
        }

    def fingerprint_parts(self) -> dict[str, Digest]:
        """A `Digest` of each part of the study that decides a sample's value, by
        name: `settings` (samples, key, sampling, times), `solver options`,
        `model` (its arrays and static fields: convention, connectivity, ...),
        `y_init`, `ydot_init`, `forces`, `parameters['name']` (its leaf, law and
        sampler) and `outputs['name']`.

        Callables are digested by what they compute (their jaxpr, see the module
        `elasticoop.montecarlo.fingerprint`), so a changed output, distribution
        function, inverse CDF, `where` or feedback force changes its part's digest.
        What could not be digested is listed in the part's `Digest.unverified`."""
        inputs = self.inputs
        parts = {
            "settings": Digest().value(
                (self.n_samples, self.key_data, self.sampling, self.initial, self.ts)
            ),
            "solver options": Digest().value(self.options),
            "model": Digest().value(inputs.model),
            "y_init": Digest().value(inputs.y_init),
            "ydot_init": Digest().value(inputs.ydot_init),
        }
        forces = Digest().value(inputs.forces, callables_traced=True)
        if inputs.forces is not None:
            t = jax.ShapeDtypeStruct((), np.asarray(self.ts).dtype)
            y = abstract(inputs.y_init)
            forces.computation(inputs.forces, t, y, y)
        parts["forces"] = forces
        abstract_inputs = abstract(inputs)
        for p in self.parameters:
            shape, law = self.leaf_shapes[p.name], p.distribution
            part = Digest().value(p, callables_traced=True)
            part.computation(p.nominal, abstract_inputs)
            if self.sampling != "random":
                u = jax.ShapeDtypeStruct(shape, jnp.float64)
                part.computation(law.ppf, u)
            else:
                key = jax.ShapeDtypeStruct((2,), jnp.uint32)
                part.computation(
                    lambda k, law=law, s=shape: law.sample(
                        jax.random.wrap_key_data(k), s
                    ),
                    key,
                )
            parts[f"parameters[{p.name!r}]"] = part
        traj = eqx.filter_eval_shape(self.simulate, inputs)
        for name, out in self.outputs.items():
            part = Digest().value(out, callables_traced=True)
            parts[f"outputs[{name!r}]"] = part.computation(out, traj)
        return parts

    def fingerprint(self) -> str:
        """SHA-256 of `describe()` and of the digests of `fingerprint_parts()`:
        equal fingerprints mean the same study (every sample the same value)."""
        return combined_fingerprint(self.describe(), self.fingerprint_parts())


def _options(options, solver, rtol, atol, max_steps) -> SimulationOptions:
    """The study's `SimulationOptions`: `options`, or built from the deprecated
    keywords."""
    given = {
        name: value
        for name, value in (
            ("solver", solver),
            ("rtol", rtol),
            ("atol", atol),
            ("max_steps", max_steps),
        )
        if value is not None
    }
    if given:
        names = ", ".join(given)
        if options is not None:
            raise ValueError(
                f"Study: give the solver settings in options only, not also as {names}"
            )
        warnings.warn(
            f"Study({names}=...) is deprecated: pass options=SimulationOptions("
            f"{', '.join(f'{k}=...' for k in given)}) instead",
            DeprecationWarning,
            stacklevel=3,
        )
        return SimulationOptions(**given, owner="Study")
    if options is None:
        return SimulationOptions(owner="Study")
    if not isinstance(options, SimulationOptions):
        raise ValueError(
            f"Study.options must be a SimulationOptions, got {type(options).__name__}"
        )
    return options


def _rest(inputs: Inputs, t0, guess) -> jax.Array:
    """The closed-loop rest state of `inputs` (NaN where the solver does not
    converge): every coordinate free, sought from `guess`, under the force law of
    `inputs` at rest at `t0` (`closed_loop_rest`)."""
    return closed_loop_rest(inputs.model, guess, inputs.forces, t0, throw=False)


def _connection_names(model, given, bodies) -> tuple[str, ...] | None:
    """The connections' labels of a `MobileModel` (`None` for other models)."""
    if not isinstance(model, MobileModel):
        if given is not None:
            raise ValueError(
                "Study.connection_names: only a MobileModel has connections"
            )
        return None
    return connection_names(given, model.connectivity, bodies)


def combined_fingerprint(description: dict, parts: Mapping[str, Digest]) -> str:
    """SHA-256 of a study's `describe()` and its parts' digests."""
    digests = {name: part.hexdigest() for name, part in parts.items()}
    text = json.dumps({"study": description, "parts": digests}, sort_keys=True)
    return hashlib.sha256(text.encode()).hexdigest()


def _check_labelled(what: str, dims, shape, labels: dict) -> None:
    """Axes named like the labelled ones (`time`, `body`, ...) must match them."""
    for axis, (dim, length) in enumerate(zip(dims, shape)):
        if dim in labels and length != len(labels[dim]):
            raise ValueError(
                f"{what}: axis {axis} is named {dim!r}, which has {len(labels[dim])} "
                f"entries in this study, but has length {length}"
            )


def admissible_inputs(inputs: Inputs):
    """Whether the model and the forces of `inputs` pass their constructors'
    checks (`AbstractElasticModel.admissible`, `force_admissible`), traced or
    not."""
    return inputs.model.admissible() & force_admissible(inputs.forces)


class _Marker:
    """A leaf that marks the one a parameter selects."""


def sample_inputs(study: Study, index, strata_row) -> tuple[Inputs, dict, jax.Array]:
    """Draw sample `index`: its inputs (before its start is set, see
    `Study.start`), the values drawn by parameter name, and whether they are
    valid. A sample whose draws are not finite, or give a model or force that no
    constructor would accept (a mass, a principal moment or, for the mobile
    model, a stiffness, damping or rest length out of range, a lift of no
    duration: `AbstractElasticModel.admissible`, `force_admissible`), gets the
    nominal values in its inputs (and is reported as `INVALID_SAMPLE`), with the
    values drawn."""
    raw = draw(study, index, strata_row)
    valid = jnp.array(True)
    for value in raw.values():
        valid = valid & jnp.all(jnp.isfinite(value))
    drawn = study.inputs
    for p in study.parameters:
        drawn = p.apply(drawn, raw[p.name])
    valid = valid & admissible_inputs(drawn)
    inputs = study.inputs
    for p in study.parameters:
        fallback = 1.0 if p.relative else p.nominal(study.inputs)
        inputs = p.apply(inputs, jnp.where(valid, raw[p.name], fallback))
    # the values drawn (those simulated where valid)
    values = {p.name: p.nominal(drawn) for p in study.parameters}
    return inputs, values, valid


def sample_start(study: Study, index, strata_row) -> jax.Array:
    """The initial state of sample `index` (`Study.start`), `(bodies, 6)`."""
    inputs, _, _ = sample_inputs(study, index, strata_row)
    return study.start(inputs).y_init


def one_sample(
    study: Study,
    index,
    strata_row,
    started=True,
    batch_loop: bool | int = False,
    y_start=None,
) -> dict:
    """Draw (`sample_inputs`), start (`Study.start`), simulate and reduce sample
    `index`: its record (sample number, status, event time, parameter values,
    outputs); an invalid sample is simulated at the nominal values and reported
    as `INVALID_SAMPLE`. `batch_loop`: passed to `simulate` (a `vmap` over
    samples integrates them in one loop). `y_start`: the sample's initial state
    when it is computed apart (`sample_start`; at rest). Where `started` is false
    the sample is not simulated: its start is made NaN, so the solve stops at its
    first step (the padding of a batch)."""
    inputs, values, valid = sample_inputs(study, index, strata_row)
    if y_start is None:
        inputs = study.start(inputs)
    else:
        inputs = eqx.tree_at(
            lambda i: (i.y_init, i.ydot_init),
            inputs,
            (y_start, jnp.zeros_like(y_start)),
        )
    inputs = eqx.tree_at(
        lambda i: i.y_init, inputs, jnp.where(started, inputs.y_init, jnp.nan)
    )
    traj = study.simulate(inputs, batch_loop=batch_loop)
    outputs = {
        name: jnp.where(valid, out(traj), jnp.nan)
        for name, out in study.outputs.items()
    }
    return {
        "sample": jnp.asarray(index, jnp.int64),
        "status": jnp.where(valid, traj.status, INVALID_SAMPLE).astype(jnp.int32),
        "event_time": jnp.where(valid, traj.event_time, jnp.nan),
        **values,
        **outputs,
    }


_record_shapes = eqx.filter_jit(one_sample)


def _inputs_hash(inputs: Inputs) -> str:
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(inputs):
        arr = np.ascontiguousarray(np.asarray(leaf))
        digest.update(str((arr.dtype, arr.shape)).encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()
