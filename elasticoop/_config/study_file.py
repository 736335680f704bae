"""Study file -> `montecarlo.Study`: a TOML file that points at a scenario and says
what varies, what is kept, how many samples are drawn and how.

Every problem of the file is collected and reported at once (`StudyFileError`,
naming the table, key and value), like the scenario files' problems.
"""

import dataclasses
import importlib.resources
import pathlib
import tomllib
from typing import Any

import jax.numpy as jnp
import numpy as np
from pydantic import TypeAdapter, ValidationError

from .._forces import PoseTracking, sampled_interval
from .._models import MobileModel
from .._naming import coordinate_names
from .._scenario import Scenario
from ..montecarlo import (
    AbstractDistribution,
    LogNormal,
    Normal,
    Parameter,
    Study,
    Uniform,
)
from .build import load_scenario
from .limits import MAX_SCENARIO_FILE_BYTES, format_bytes, output_limit_problem
from .problems import Problem, Problems, ScenarioError, message_of, unknown_key_message
from .study_quantities import INERTIA_AXES, OUTPUTS, QUANTITIES
from .study_schema import (
    STUDY_REQUIRED,
    STUDY_SECTIONS,
    STUDY_TOP_LEVEL_KEYS,
    ParameterTable,
    SensitivityTable,
    StudyInfo,
)

# How far into the tail of a normal law the sign of a quantity is checked: a draw
# beyond 5 standard deviations has a probability of about 3e-7.
NORMAL_TAIL = 5.0

_ADAPTERS: dict[str, TypeAdapter[Any]] = {
    name: TypeAdapter(cls) for name, (cls, shape) in STUDY_SECTIONS.items()
}


class StudyFileError(ScenarioError):
    """A study file is invalid; `.problems` lists every problem found, each with
    its table, key and message, and `str(error)` names the file and all of them."""

    what = "study file"


@dataclasses.dataclass(frozen=True)
class StudyFile:
    """A study file, read: the `Study` it describes, the scenario it varies, and
    the thresholds of each output (`P(output > threshold)` is reported).

    - `study`: the `montecarlo.Study`.
    - `scenario`: the nominal `Scenario` (with the study's `[time]` and `[solver]`).
    - `thresholds`: output name -> thresholds, in the output's unit.
    - `units`: output name -> unit of its values.
    - `name`, `description`, `source` (the study file), `scenario_file`.
    """

    study: Study
    scenario: Scenario
    thresholds: dict[str, tuple[float, ...]]
    units: dict[str, str]
    name: str
    description: str
    source: str
    scenario_file: str
    sensitivity: SensitivityTable | None = None


def load_study(path, samples: int | None = None) -> StudyFile:
    """Read and validate a TOML study file, load its scenario and build the
    `montecarlo.Study`.

    **Arguments:**

    - `path`: the study file.
    - `samples`: a number of samples to draw instead of the file's
      `[sampling] samples` (e.g. a small trial run).

    **Returns:** a `StudyFile`. Raises `StudyFileError` (a `ValueError`) listing
    every problem of the file, or the scenario's `ScenarioError`.
    """
    path = pathlib.Path(path)

    def refuse(message: str) -> StudyFileError:
        return StudyFileError(str(path), [Problem("(file)", "", message)])

    if path.is_dir():
        raise refuse("a folder, not a study file")
    if not path.is_file():
        raise refuse("no such study file")
    size = path.stat().st_size
    if size > MAX_SCENARIO_FILE_BYTES:
        raise refuse(
            f"the file holds {format_bytes(size)}, over the limit of "
            f"{format_bytes(MAX_SCENARIO_FILE_BYTES)} for a study file"
        )
    try:
        raw = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise refuse(f"not valid TOML: {err}") from None
    except RecursionError:
        raise refuse("not a usable TOML file: nested too deeply to read") from None
    except OSError as err:
        raise refuse(f"cannot be read ({err.strerror})") from None
    return _StudyBuilder(raw, path, samples).build()


def shipped_scenario(name: str) -> pathlib.Path | None:
    """The file of the shipped example scenario `name`, when it exists as a file."""
    file = importlib.resources.files("elasticoop") / "scenarios" / f"{name}.toml"
    if not file.is_file():
        return None
    path = pathlib.Path(str(file))
    return path if path.is_file() else None


def _label(section: str, k: int, entry) -> str:
    label = None
    if isinstance(entry, dict):
        label = entry.get("name", entry.get("quantity"))
    return f"[[{section}]] #{k + 1}" + (f" ({label})" if isinstance(label, str) else "")


class _StudyBuilder:
    def __init__(self, raw: dict, path: pathlib.Path, samples: int | None):
        self.raw = raw
        self.path = path
        self.samples = samples
        self.problems = Problems(str(path), StudyFileError)
        self.s: dict[str, Any] = {}

    def add(self, table: str, key: str, message: str) -> None:
        self.problems.add(table, key, message)

    def build(self) -> StudyFile:
        self.validate_tables()
        scenario, scenario_file = self.scenario()
        parameters, outputs, thresholds, units = [], {}, {}, {}
        if scenario is not None:
            scenario = self.with_time_and_solver(scenario)
            parameters = self.parameters(scenario)
            outputs, thresholds, units = self.outputs(scenario)
            self.check_sensitivity(outputs)
            clash = {p.name for p in parameters} & set(outputs)
            for name in sorted(clash):
                self.add(
                    "[[outputs]]",
                    "name",
                    f"'{name}' names both a parameter and an output",
                )
        initial = self.initial(scenario)
        self.problems.raise_if_any()
        assert scenario is not None and self.info is not None  # else: problems
        sampling = self.s["sampling"]
        try:
            study = Study(
                scenario.model,
                scenario.y_init,
                scenario.ydot_init,
                scenario.ts,
                parameters=parameters,
                outputs=outputs,
                n_samples=self.samples or sampling.samples,
                key=sampling.seed,
                forces=scenario.forces,
                sampling=sampling.method,
                options=scenario.options,
                body_names=scenario.names,
                connection_names=scenario.connection_names or None,
                initial=initial,
            )
        except ValueError as err:
            if initial != "equilibrium" or "rest state" not in str(err):
                raise
            self.add("[initial]", "from", f"'equilibrium': {err}")
            self.problems.raise_if_any()
            raise
        return StudyFile(
            study=study,
            scenario=scenario,
            thresholds=thresholds,
            units=units,
            name=self.info.name or self.path.stem,
            description=self.info.description,
            source=str(self.path),
            scenario_file=scenario_file,
            sensitivity=self.s.get("sensitivity"),
        )

    def check_sensitivity(self, outputs: dict) -> None:
        """The `[sensitivity]` table's outputs are the study's. (A name of an
        `[[outputs]]` table with a problem of its own, which is reported, is not
        reported again here.)"""
        table = self.s.get("sensitivity")
        declared = {
            entry.get("name", entry.get("quantity"))
            for entry in self.raw.get("outputs") or []
            if isinstance(entry, dict)
        }
        for name in (table.outputs or []) if table is not None else []:
            if name not in outputs and name not in declared:
                self.add(
                    "[sensitivity]",
                    "outputs",
                    f"no output named {name!r} (the study's outputs: "
                    f"{', '.join(outputs)})",
                )

    # -- every table on its own ---------------------------------------------------
    def validate_tables(self) -> None:
        allowed = [*STUDY_SECTIONS, *STUDY_TOP_LEVEL_KEYS]
        for key in self.raw:
            if key not in allowed:
                self.add("(top level)", key, unknown_key_message(key, allowed))
        top = {k: self.raw[k] for k in STUDY_TOP_LEVEL_KEYS if k in self.raw}
        try:
            self.info: StudyInfo | None = StudyInfo.model_validate(top)
        except ValidationError as err:
            self.info = None
            for e in err.errors():
                self.add(
                    "(top level)", ".".join(map(str, e["loc"])), message_of(dict(e))
                )
        for name, (cls, shape) in STUDY_SECTIONS.items():
            if name not in self.raw:
                if name in STUDY_REQUIRED:
                    table = f"[[{name}]]" if shape == "array" else f"[{name}]"
                    self.add(table, "", "missing table")
                continue
            raw = self.raw[name]
            if shape == "array":
                if not isinstance(raw, list) or not raw:
                    self.add(
                        f"[[{name}]]",
                        "",
                        f"give one or more [[{name}]] tables, got {raw!r:.60}",
                    )
                    continue
                self.s[name] = [self._entry(name, cls, raw, k) for k in range(len(raw))]
                continue
            try:
                self.s[name] = _ADAPTERS[name].validate_python(raw)
            except ValidationError as err:
                self.problems.add_validation_error(name, shape, raw, err)

    def _entry(self, name, cls, raw, k):
        try:
            return cls.model_validate(raw[k])
        except ValidationError as err:
            for e in err.errors():
                key = "".join(
                    f"[{p}]" if isinstance(p, int) else f".{p}" for p in e["loc"]
                ).lstrip(".")
                self.add(_label(name, k, raw[k]), key, message_of(dict(e)))
            return None

    def initial(self, scenario: Scenario | None) -> str:
        """`Study.initial` from `[initial] from` (default `"equilibrium"`)."""
        table = self.s.get("initial")
        start = "equilibrium" if table is None else table.start
        if scenario is None:
            return "given"
        if start == "equilibrium" and np.any(np.asarray(scenario.ydot_init) != 0):
            self.add(
                "[initial]",
                "from",
                "'equilibrium' (the default) starts every sample at rest, but the "
                'scenario starts with velocities; give from = "scenario" to start '
                "every sample from the scenario's initial state",
            )
        return "given" if start == "scenario" else "equilibrium"

    # -- the scenario -------------------------------------------------------------
    def scenario(self) -> tuple[Scenario | None, str]:
        if self.info is None:
            return None, ""
        given = self.info.scenario
        file = self.path.parent / given
        if not file.is_file():
            shipped = shipped_scenario(given) if "/" not in given else None
            if shipped is None:
                self.add(
                    "(top level)",
                    "scenario",
                    f"no scenario file {given!r} in the study file's folder "
                    f"({self.path.parent}), and no shipped example of that name "
                    f"(see 'elasticoop examples')",
                )
                return None, ""
            file = shipped
        try:
            scenario = load_scenario(file)
        except ScenarioError as err:
            self.add(
                "(top level)",
                "scenario",
                "the scenario is invalid:\n    " + str(err).replace("\n", "\n    "),
            )
            return None, str(file)
        if scenario.prescribed is not None:
            self.add(
                "(top level)",
                "scenario",
                f"{file} prescribes coordinates ([prescribed]), which a Monte Carlo "
                f"study does not support",
            )
            return None, str(file)
        return scenario, str(file)

    def with_time_and_solver(self, scenario: Scenario) -> Scenario:
        ts = np.asarray(scenario.ts)
        time = self.s.get("time")
        if time is not None:
            start = ts[0] if time.start is None else time.start
            stop = ts[-1] if time.stop is None else time.stop
            n = len(ts) if time.samples is None else time.samples
            problem = output_limit_problem(
                n, scenario.model.n_bodies, len(scenario.connection_names or ())
            )
            if problem is not None:
                # before the times are made (2e9 samples: 16 GB)
                self.add("[time]", "samples", problem)
                return scenario
            if not stop > start:
                self.add(
                    "[time]",
                    "stop",
                    f"empty time span: stop ({stop}) must be greater than start "
                    f"({start})",
                )
            else:
                ts = np.linspace(start, stop, n)
        solver = self.s.get("solver")
        changes: dict[str, Any] = {"ts": jnp.asarray(ts)}
        interval = sampled_interval(scenario.forces)
        if interval is not None:
            lo, hi = (float(t) for t in interval)
            for key, t in (("start", ts[0]), ("stop", ts[-1])):
                if not lo <= t <= hi:
                    self.add(
                        "[time]",
                        key,
                        f"{t} s is outside the scenario's force samples, which cover "
                        f"[{lo}, {hi}] s (samples are not extrapolated)",
                    )
        if isinstance(scenario.forces, PoseTracking):
            # the lift begins where the study's runs begin
            changes["forces"] = dataclasses.replace(
                scenario.forces, start=jnp.asarray(float(ts[0]))
            )
        if solver is not None:
            given = {k: v for k, v in solver.model_dump().items() if v is not None}
            changes["options"] = dataclasses.replace(scenario.options, **given)
        return dataclasses.replace(scenario, **changes)  # type: ignore[type-var]

    # -- what varies ----------------------------------------------------------------
    def parameters(self, scenario: Scenario) -> list[Parameter]:
        built: list[Parameter] = []
        quantities: dict[str, str] = {}
        names: dict[str, str] = {}
        for k, entry in enumerate(self.s.get("parameters") or []):
            if entry is None:
                continue
            table = _label("parameters", k, self.raw["parameters"][k])
            name = entry.name or entry.quantity
            if entry.quantity in quantities:
                self.add(
                    table,
                    "quantity",
                    f"{entry.quantity!r} is already varied by "
                    f"{quantities[entry.quantity]}: vary each quantity in one entry "
                    f"(select its entries with bodies, connections or axes)",
                )
                continue
            if name in names:
                self.add(table, "name", f"name {name!r} is used twice")
                continue
            quantities[entry.quantity] = names[name] = table
            parameter = _Parameter(self, table, entry, name, scenario).build()
            if parameter is not None:
                built.append(parameter)
        return built

    # -- what is kept ---------------------------------------------------------------
    def outputs(self, scenario: Scenario):
        outputs, thresholds, units = {}, {}, {}
        mobile = isinstance(scenario.model, MobileModel)
        for k, entry in enumerate(self.s.get("outputs") or []):
            if entry is None:
                continue
            table = _label("outputs", k, self.raw["outputs"][k])
            kind = OUTPUTS[entry.quantity]
            name = entry.name or entry.quantity
            if name in outputs:
                self.add(table, "name", f"output name {name!r} is used twice")
                continue
            if kind.mobile and not mobile:
                self.add(
                    table,
                    "quantity",
                    f"{entry.quantity!r} is defined per connection: it needs a "
                    f"scenario with [[connections]] (a mobile model)",
                )
                continue
            if entry.thresholds and kind.over_time:
                self.add(
                    table,
                    "thresholds",
                    f"{entry.quantity!r} is a time series; thresholds apply to "
                    f"outputs without a time axis: "
                    + ", ".join(n for n, o in OUTPUTS.items() if not o.over_time),
                )
                continue
            outputs[name] = kind.make()
            thresholds[name] = tuple(entry.thresholds)
            units[name] = kind.unit
        return outputs, thresholds, units


class _Parameter:
    """One `[[parameters]]` entry against the scenario -> a `montecarlo.Parameter`
    (problems are added to the builder)."""

    def __init__(self, builder, table, entry: ParameterTable, name, scenario):
        self.builder = builder
        self.table = table
        self.entry = entry
        self.name = name
        self.scenario = scenario
        self.quantity = QUANTITIES[entry.quantity]

    def add(self, key: str, message: str) -> None:
        self.builder.add(self.table, key, message)

    def build(self) -> Parameter | None:
        entry, q, scenario = self.entry, self.quantity, self.scenario
        if q.needs == "mobile" and not isinstance(scenario.model, MobileModel):
            self.add(
                "quantity",
                f"{entry.quantity!r} belongs to the connections of a mobile model; "
                f"the scenario has none (the K and D matrices of an immobile model "
                f"cannot be varied from a study file)",
            )
            return None
        if q.needs == "pose_tracking" and not isinstance(scenario.forces, PoseTracking):
            self.add(
                "quantity",
                f"{entry.quantity!r} is a setting of [forces.pose_tracking], which "
                f"the scenario does not use",
            )
            return None
        nominal = np.asarray(q.where(getattr(scenario, q.target)), dtype=np.float64)
        mask = self.selection(nominal.shape)
        spread = self.spread(nominal.shape)
        if mask is None or spread is None:
            return None
        relative = entry.relative_spread is not None
        width = np.where(mask, spread, 0.0)
        centre = np.ones_like(nominal) if relative else nominal
        law: AbstractDistribution
        if entry.distribution == "lognormal":
            law = LogNormal(np.zeros_like(nominal), width)
            low = None
        elif entry.distribution == "normal":
            law = Normal(centre, width)
            low = centre - NORMAL_TAIL * width
        else:
            law = Uniform(centre - width, centre + width)
            low = centre - width
        if low is not None:
            lowest = low * nominal if relative else low
            if not self.sign_ok(lowest, mask):
                return None
        return Parameter(
            self.name,
            q.where,
            law,
            target=q.target,
            relative=relative,
            dims=self.dims(nominal.ndim),
        )

    def dims(self, ndim: int) -> tuple[str, ...]:
        dims = []
        for d in self.quantity.dims[:ndim]:
            dims.append(f"{self.name}_axis" if d == "inertia_axis" else d)
        return tuple(dims)

    def axis_names(self) -> tuple[str, ...]:
        if "coordinate" in self.quantity.dims:
            return coordinate_names(self.scenario.model.convention)
        if "inertia_axis" in self.quantity.dims:
            return INERTIA_AXES
        return ()

    def selection(self, shape) -> np.ndarray | None:
        """The selected entries of the leaf (`bodies`, `connections`, `axes`)."""
        entry, dims = self.entry, self.quantity.dims
        mask = np.ones(shape, dtype=bool)
        ok = True
        options = {
            "bodies": ("body", self.scenario.names),
            "connections": ("connection", self.scenario.connection_names),
            "axes": (None, self.axis_names()),
        }
        for key, (dim, names) in options.items():
            wanted = getattr(entry, key)
            if wanted is None:
                continue
            axis = len(dims) - 1 if key == "axes" else None
            if key != "axes" and dim in dims:
                axis = dims.index(dim)
            if axis is None or axis < 0 or (key == "axes" and not names):
                self.add(
                    key,
                    f"{self.entry.quantity!r} has no {key} to select"
                    + (f" (its axes: {', '.join(dims)})" if dims else " (a scalar)"),
                )
                ok = False
                continue
            unknown = [w for w in wanted if w not in names]
            if unknown:
                self.add(
                    key,
                    f"no {key[:-1] if key != 'bodies' else 'body'} named "
                    f"{unknown[0]!r} (choose from {', '.join(names)})",
                )
                ok = False
                continue
            index = [k for k, n in enumerate(names) if n in wanted]
            keep = np.zeros(shape[axis], dtype=bool)
            keep[index] = True
            mask &= np.expand_dims(keep, [a for a in range(len(shape)) if a != axis])
        return mask if ok else None

    def spread(self, shape) -> np.ndarray | None:
        """The spread of every entry of the leaf: a number, or one per selected
        axis (placed along the last axis)."""
        entry = self.entry
        key = (
            "relative_spread"
            if entry.relative_spread is not None
            else ("absolute_spread")
        )
        value = getattr(entry, key)
        if not isinstance(value, list):
            return np.full(shape, float(value))
        names = self.axis_names()
        if not names:
            self.add(
                key,
                f"{entry.quantity!r} has no axes: give one number, got a list",
            )
            return None
        selected = [n for n in names if entry.axes is None or n in entry.axes]
        if len(value) != len(selected):
            self.add(
                key,
                f"give one number, or one per selected axis ({len(selected)}: "
                f"{', '.join(selected)}), got {len(value)} numbers",
            )
            return None
        row = np.zeros(len(names))
        row[[names.index(n) for n in selected]] = value
        return np.broadcast_to(row, shape).copy()

    def sign_ok(self, low, mask) -> bool:
        """Whether the lowest value the law reaches (within `NORMAL_TAIL`
        standard deviations for a normal law) keeps the quantity's sign."""
        sign = self.quantity.sign
        if sign is None:
            return True
        bad = mask & ((low <= 0) if sign == "positive" else (low < 0))
        if not bad.any():
            return True
        lowest = float(np.min(np.where(mask, low, np.inf)))
        what = (
            "within 5 standard deviations"
            if self.entry.distribution == "normal"
            else "at the low end of its range"
        )
        self.add(
            "relative_spread"
            if self.entry.relative_spread is not None
            else "absolute_spread",
            f"{self.entry.quantity!r} must stay {sign}, but the "
            f"{self.entry.distribution} law reaches {lowest:g} {what}; use a "
            f"smaller spread or a lognormal law",
        )
        return False
