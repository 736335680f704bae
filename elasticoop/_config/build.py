"""Scenario file -> `Scenario`: parse TOML, validate every table, check the tables
against each other, and build the model, forces and prescribed coordinates."""

import dataclasses
import math
import pathlib
import tomllib
from typing import Any

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from pydantic import TypeAdapter, ValidationError

from .._body import RigidBody
from .._forces import ConstantForce, PoseTracking, SampledForce
from .._models import AbstractElasticModel, Connection, ImmobileModel, MobileModel
from .._models.immobile import check_stiffness, check_symmetric_psd
from .._naming import coordinate_names
from .._options import GIMBAL_TOL, SimulationOptions
from .._rotations import get_rotation
from .._scenario import IdentifySpec, PrescribedSpec, Scenario
from .data_files import read_matrix, read_series
from .identify_settings import identify_spec_problems
from .initial import (
    INITIAL_FROM,
    equilibrium_start,
    forces_at_start,
    held_coordinates,
    holding_forces,
)
from .limits import (
    MAX_OUTPUT_BYTES,
    MAX_SAMPLES_BYTES,
    MAX_SCENARIO_FILE_BYTES,
    format_bytes,
    output_bytes,
    output_numbers_per_sample,
)
from .problems import (
    Problem,
    Problems,
    ScenarioError,
    message_of,
    show_value,
    unknown_key_message,
)
from .schema import REQUIRED, SECTIONS, TOP_LEVEL_KEYS, Name, ScenarioInfo, SolverTable

# Generalized force components in a forces CSV: world force [N], then the
# generalized torques conjugate to the three Euler angles [N m].
FORCE_COMPONENTS = ("fx", "fy", "fz", "q1", "q2", "q3")

_ADAPTERS: dict[str, TypeAdapter[Any]] = {
    name: TypeAdapter(
        # `cls` is a table class: a type, though a variable to type checkers.
        {"table": cls, "array": list[cls], "by_body": dict[Name, cls]}[shape]  # type: ignore[valid-type]
    )
    for name, (cls, shape) in SECTIONS.items()
}


def load_scenario(path) -> Scenario:
    """Read and validate a TOML scenario file.

    Every problem found (unknown key, wrong type, missing body, bad unit, bad data
    file, ...) is collected, and one `ScenarioError` (a `ValueError`) lists them
    all, each with its table and key. Data files are looked up relative to the
    scenario file's folder.

    **Returns:** a `Scenario`.
    """
    path = pathlib.Path(path)

    def refuse(message: str) -> ScenarioError:
        return ScenarioError(str(path), [Problem("(file)", "", message)])

    if path.is_dir():
        raise refuse("a folder, not a scenario file")
    if not path.is_file():
        raise refuse("no such scenario file")
    size = path.stat().st_size
    if size > MAX_SCENARIO_FILE_BYTES:
        raise refuse(
            f"the file holds {format_bytes(size)}, over the limit of "
            f"{format_bytes(MAX_SCENARIO_FILE_BYTES)} for a scenario file (put large "
            f"matrices and time series in data files)"
        )
    try:
        # "utf-8-sig": a byte-order mark (as some editors write) is dropped
        raw = tomllib.loads(path.read_text(encoding="utf-8-sig"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as err:
        raise refuse(f"not valid TOML: {err}") from None
    except RecursionError:
        raise refuse(
            "not a usable TOML file: arrays or tables are nested too deeply to read"
        ) from None
    return build_scenario(raw, source=str(path), base_dir=path.parent)


def build_scenario(raw: dict, source: str = "<scenario>", base_dir=".") -> Scenario:
    """Validate the parsed TOML `raw` (a dict) and build its `Scenario`."""
    return _Builder(raw, source, pathlib.Path(base_dir)).build()


def _array_label(section: str, k: int, entry) -> str:
    name = entry.get("name") if isinstance(entry, dict) else None
    return f"[[{section}]] #{k + 1}" + (f" ({name})" if isinstance(name, str) else "")


class _Builder:
    y_init: np.ndarray | None

    def __init__(self, raw, source, base_dir):
        self.raw = raw
        self.source = source
        self.base_dir = base_dir
        self.problems = Problems(source)
        self.s = {}  # validated sections
        self.initial_from = None  # `[initial] from`
        self.hold_feedforward = False  # pose tracking with feedforward = "hold"

    def add(self, table, key, message):
        self.problems.add(table, key, message)

    # -- stage 1: every table on its own ------------------------------------------
    def validate_tables(self):
        allowed = [*SECTIONS, *TOP_LEVEL_KEYS]
        for key in self.raw:
            if key not in allowed:
                self.add("(top level)", key, unknown_key_message(key, allowed))
        top = {k: self.raw[k] for k in TOP_LEVEL_KEYS if k in self.raw}
        try:
            self.info = ScenarioInfo.model_validate(top)
        except ValidationError as err:
            self.info = None
            for e in err.errors():
                self.add("(top level)", ".".join(map(str, e["loc"])), message_of(e))
        for name, (_, shape) in SECTIONS.items():
            if name not in self.raw:
                if name in REQUIRED:
                    table = f"[[{name}]]" if shape == "array" else f"[{name}]"
                    self.add(table, "", "missing table")
                continue
            raw = self.raw[name]
            if name == "initial":
                raw = self.initial_option(raw)
            if shape == "array" and isinstance(raw, list):
                # entry by entry, so that valid entries still take part in the
                # checks across tables (None marks an invalid entry)
                self.s[name] = [
                    self._validate_entry(name, raw, k) for k in range(len(raw))
                ]
                continue
            try:
                self.s[name] = _ADAPTERS[name].validate_python(raw)
            except ValidationError as err:
                self.problems.add_validation_error(name, shape, raw, err)

    def initial_option(self, raw):
        """Take the option `from` (a string; a table of that name is a body's) out
        of `[initial]` and check it; returns the body tables."""
        self.initial_from = None
        if not isinstance(raw, dict) or not isinstance(raw.get("from"), str):
            return raw
        value = raw["from"]
        if value in INITIAL_FROM:
            self.initial_from = value
        else:
            choices = " or ".join(f'"{v}"' for v in INITIAL_FROM)
            self.add(
                "[initial]",
                "from",
                f"must be {choices} (or left out for the poses as given), got "
                f"{show_value(value)}",
            )
        return {k: v for k, v in raw.items() if k != "from"}

    def _validate_entry(self, name, raw, k):
        cls = SECTIONS[name][0]
        try:
            return cls.model_validate(raw[k])
        except ValidationError as err:
            self.problems.add_validation_error(name, "array", raw, err, prefix=(k,))
            return None

    # -- stage 2: tables against each other --------------------------------------
    def check_bodies(self):
        bodies = self.s.get("bodies")
        if bodies is None:
            return
        if not bodies:
            self.add("[[bodies]]", "", "needs at least one body (the object)")
        if any(b is None for b in bodies):
            # names of invalid entries are still known when they are strings
            raw = self.raw["bodies"]
            names = [e.get("name") if isinstance(e, dict) else None for e in raw]
            self.names = [
                n if isinstance(n, str) else f"#{k + 1}" for k, n in enumerate(names)
            ]
            self.index = {name: k for k, name in enumerate(self.names)}
            self.bodies_valid = False
            return
        self.bodies_valid = True
        seen = {}
        for k, body in enumerate(bodies):
            if body.name in seen:
                self.add(
                    _array_label("bodies", k, self.raw["bodies"][k]),
                    "name",
                    f"body name '{body.name}' is used twice (also #{seen[body.name]})",
                )
            seen.setdefault(body.name, k + 1)
        self.names = [b.name for b in bodies]
        self.index = {name: k for k, name in enumerate(self.names)}
        self.rigid_bodies = []
        for k, body in enumerate(bodies):
            try:
                self.rigid_bodies.append(RigidBody(body.mass, body.inertia))
            except ValueError as err:
                key = "inertia" if "inertia" in str(err) else "mass"
                label = _array_label("bodies", k, self.raw["bodies"][k])
                self.add(label, key, str(err))
                self.bodies_valid = False

    def body_problem(self, name) -> str:
        return f"no body named '{name}' (bodies: {', '.join(self.names)})"

    def poses(self, section, rates):
        """`(bodies, 6)` poses (and rates) from `[initial.*]` or `[unloaded.*]`."""
        tables = self.s.get(section)
        if tables is None or self.index is None:
            return None
        y, ydot = np.zeros((len(self.names), 6)), np.zeros((len(self.names), 6))
        for name, pose in tables.items():
            if name not in self.index:
                self.add(f"[{section}.{name}]", "", self.body_problem(name))
                continue
            k = self.index[name]
            y[k] = [*pose.position, *pose.angles.to_radians()]
            if rates:
                ydot[k, :3] = pose.velocity
                if pose.angle_rates is not None:
                    ydot[k, 3:] = pose.angle_rates.to_radians()
                if self.initial_from is not None and np.any(ydot[k]):
                    moving = "velocity" if np.any(ydot[k, :3]) else "angle_rates"
                    self.add(
                        f"[{section}.{name}]",
                        moving,
                        f'from = "{self.initial_from}" starts at rest: leave out '
                        "velocity and angle_rates",
                    )
            try:
                self.rotation.check_regular(
                    y[k : k + 1, 3:], GIMBAL_TOL, f"[{section}]", [name]
                )
            except ValueError as err:
                self.add(f"[{section}.{name}]", "angles", str(err))
        missing = [n for n in self.names if n not in tables]
        for name in missing:
            self.add(
                f"[{section}.{name}]", "", f"missing table: body '{name}' needs one"
            )
        return (y, ydot) if rates else y

    def check_time(self):
        time = self.s.get("time")
        if time is None:
            return None
        if not time.stop > time.start:
            self.add(
                "[time]",
                "stop",
                f"empty time span: stop ({time.stop}) must be greater than start "
                f"({time.start})",
            )
            return None
        if not self.output_fits(time.samples):
            return None
        return np.linspace(time.start, time.stop, time.samples)

    def output_fits(self, samples: int) -> bool:
        """Whether the results of `samples` output times fit `MAX_OUTPUT_BYTES`
        (with the bodies and connections the file names); adds the problem if not."""
        n_bodies = len(self.names) if self.names else 1
        connections = self.raw.get("connections")
        n_connections = len(connections) if isinstance(connections, list) else 0
        prescribed = "prescribed" in self.raw
        size = output_bytes(samples, n_bodies, n_connections, prescribed)
        if size <= MAX_OUTPUT_BYTES:
            return True
        per_sample = output_numbers_per_sample(n_bodies, n_connections, prescribed)
        most = MAX_OUTPUT_BYTES // (8 * per_sample)
        self.add(
            "[time]",
            "samples",
            f"the results would need {format_bytes(size)} for samples = "
            f"{show_value(samples)} ({per_sample} float64 numbers per sample for "
            f"{n_bodies} bod{'y' if n_bodies == 1 else 'ies'} and {n_connections} "
            f"connection{'' if n_connections == 1 else 's'}), over the limit of "
            f"{format_bytes(MAX_OUTPUT_BYTES)}; use at most {most} samples",
        )
        return False

    def matrix(self, key, value):
        if isinstance(value, str):
            try:
                return read_matrix(self.base_dir, value)
            except ValueError as err:
                self.add("[immobile]", key, str(err))
                return None
        if not value:
            self.add("[immobile]", key, "is empty (give the matrix's rows)")
            return None
        rows = {len(r) for r in value}
        if len(rows) > 1:
            self.add("[immobile]", key, "rows have different lengths")
            return None
        return np.asarray(value, dtype=np.float64).reshape(len(value), -1)

    def immobile_matrices(self):
        table = self.s.get("immobile")
        if table is None or self.index is None:
            return None
        n = len(self.names)
        size = 6 * n
        out = {}
        for key in ("K", "D"):
            mat = self.matrix(key, getattr(table, key))
            if mat is None:
                continue
            if mat.shape != (size, size):
                self.add(
                    "[immobile]",
                    key,
                    f"must be 6(m+1) x 6(m+1) = {size} x {size} for {n} bodies, got "
                    f"{mat.shape[0]} x {mat.shape[1]}",
                )
                continue
            try:
                if key == "K":
                    check_stiffness(mat, n)
                else:
                    check_symmetric_psd(mat, key)
            except ValueError as err:
                self.add("[immobile]", key, str(err))
                continue
            out[key] = mat
        return out

    def connections(self, unloaded):
        conns = self.s.get("connections", [])
        if self.index is None:
            return None
        built, labels = [], []
        for k, c in enumerate(conns):
            table = _array_label("connections", k, self.raw["connections"][k])
            if c is None:
                entry = self.raw["connections"][k]
                raw_bodies = entry.get("bodies") if isinstance(entry, dict) else None
                if isinstance(raw_bodies, list):
                    for b in raw_bodies:
                        if isinstance(b, str) and b not in self.index:
                            self.add(table, "bodies", self.body_problem(b))
                continue
            unknown = [b for b in c.bodies if b not in self.index]
            for b in unknown:
                self.add(table, "bodies", self.body_problem(b))
            if unknown:
                continue
            if c.bodies[0] == c.bodies[1]:
                self.add(table, "bodies", f"joins body '{c.bodies[0]}' to itself")
                continue
            i, j = (self.index[b] for b in c.bodies)
            label = c.name or f"{c.bodies[0]}-{c.bodies[1]}"
            if label in labels:
                self.add(table, "name", f"connection name '{label}' is used twice")
            labels.append(label)
            if unloaded is None:
                continue
            rest_length = (
                float(np.linalg.norm(unloaded[i, :3] - unloaded[j, :3]))
                if c.rest_length is None
                else c.rest_length
            )
            rest_angles = (
                unloaded[i, 3:] - unloaded[j, 3:]
                if c.rest_angles is None
                else np.asarray(c.rest_angles.to_radians())
            )
            built.append(
                Connection(i, j, c.stiffness, c.damping, rest_length, rest_angles)
            )
        return built, tuple(labels)

    def series_columns(self, key, name, table, allowed, what, columns_of):
        """Read a CSV; check its '<body>.<column>' names against `allowed(body)`;
        returns `(times, {(body index, column index in columns_of): values})`."""
        try:
            times, columns = read_series(self.base_dir, name)
        except ValueError as err:
            self.add(table, key, str(err))
            return None
        size = len(times) * len(self.names) * 6 * 8
        if size > MAX_SAMPLES_BYTES:
            self.add(
                table,
                key,
                f"file '{name}' has {len(times)} rows: as (rows, {len(self.names)} "
                f"bodies, 6) samples they need {format_bytes(size)}, over the limit "
                f"of {format_bytes(MAX_SAMPLES_BYTES)}; resample the file",
            )
            return None
        parsed, ok = {}, True
        for column, values in columns.items():
            body, _, part = column.partition(".")
            if body not in self.index:
                self.add(
                    table,
                    key,
                    f"file '{name}', column '{column}': " + self.body_problem(body),
                )
                ok = False
            elif part not in allowed(body):
                self.add(
                    table,
                    key,
                    f"file '{name}', column '{column}': '{part}' is not {what} "
                    f"(expected '<body>.<name>' with name one of "
                    f"{', '.join(allowed(body)) or 'none'})",
                )
                ok = False
            else:
                parsed[(self.index[body], columns_of.index(part))] = values
        if self.ts is not None and (times[0] > self.ts[0] or times[-1] < self.ts[-1]):
            self.add(
                table,
                key,
                f"file '{name}' covers t = {times[0]}..{times[-1]} s but [time] spans "
                f"{self.ts[0]}..{self.ts[-1]} s",
            )
            ok = False
        return (times, parsed) if ok else None

    def forces(self):
        table = self.s.get("forces")
        if table is None or self.index is None:
            return None
        n, m = len(self.names), len(self.names) - 1
        if table.constant is not None:
            rows = np.zeros((n, 6))
            for name, value in table.constant.items():
                if name not in self.index:
                    self.add("[forces.constant]", name, self.body_problem(name))
                    continue
                rows[self.index[name]] = value
            on_object = self.names[0] in table.constant
            return ConstantForce(rows if on_object else rows[1:])
        if table.samples is not None:
            series = self.series_columns(
                "samples",
                table.samples,
                "[forces]",
                lambda body: FORCE_COMPONENTS,
                "a force component",
                FORCE_COMPONENTS,
            )
            if series is None:
                return None
            times, parsed = series
            F = np.zeros((len(times), n, 6))
            for (k, c), values in parsed.items():
                F[:, k, c] = values
            on_object = any(k == 0 for k, _ in parsed)
            return SampledForce(times, F if on_object else F[:, 1:])
        pose = table.pose_tracking
        if m < 1:
            self.add("[forces.pose_tracking]", "", "needs at least one contact body")
            return None
        if self.y_init is None or self.model_table is None or not self.bodies_valid:
            return None
        masses = np.array([b.mass for b in self.s["bodies"]])
        feedforward = np.zeros((m, 6))
        if pose.feedforward == "weight":
            feedforward[:, 2] = masses.sum() * self.model_table.gravity / m
        elif isinstance(pose.feedforward, dict):  # the numbers themselves
            for name, values in pose.feedforward.items():
                k = self.index.get(name) if self.index else None
                if not k:  # unknown, or the object (index 0)
                    self.add(
                        "[forces.pose_tracking.feedforward]",
                        name,
                        "not a contact body (feedforward acts on the contact "
                        f"bodies: {', '.join(self.names[1:])})",
                    )
                    continue
                feedforward[k - 1] = values
        # "hold": set once the model and the initial state are known
        self.hold_feedforward = pose.feedforward == "hold"
        try:
            return PoseTracking(
                y_ref=jnp.asarray(self.y_init[1:]),
                feedforward=jnp.asarray(feedforward),
                kp=jnp.asarray(pose.kp),
                kd=jnp.asarray(pose.kd),
                height=jnp.asarray(pose.lift_height, dtype=jnp.float64),
                duration=jnp.asarray(pose.lift_time, dtype=jnp.float64),
                start=jnp.asarray(self.ts[0] if self.ts is not None else 0.0),
            )
        except ValueError as err:  # e.g. a weight beyond float64's range
            self.add("[forces.pose_tracking]", "", str(err))
            return None

    def prescribed(self):
        table = self.s.get("prescribed")
        if table is None or self.index is None:
            return None
        coords = self.coordinate_names
        mask = np.zeros((len(self.names), 6), dtype=bool)
        for name, wanted in table.coordinates.items():
            if name not in self.index:
                self.add("[prescribed.coordinates]", name, self.body_problem(name))
                continue
            if not wanted:
                self.add("[prescribed.coordinates]", name, "empty list of coordinates")
            for c in coords if wanted == ["all"] else wanted:
                if c not in coords:
                    self.add(
                        "[prescribed.coordinates]",
                        name,
                        f"unknown coordinate '{c}' (with convention "
                        f"'{self.rotation.name}': {', '.join(coords)}, or \"all\")",
                    )
                else:
                    mask[self.index[name], coords.index(c)] = True
        if self.y_init is None:
            return None
        if table.motion is None:
            return PrescribedSpec(mask, None, self.y_init.copy())
        series = self.series_columns(
            "motion.csv",
            table.motion.csv,
            "[prescribed]",
            lambda body: [c for c, on in zip(coords, mask[self.index[body]]) if on],
            "a prescribed coordinate of that body",
            coords,
        )
        if series is None:
            return None
        times, parsed = series
        values = np.broadcast_to(self.y_init, (len(times), *self.y_init.shape)).copy()
        scale = math.pi / 180 if table.motion.angle_unit == "degrees" else 1.0
        for (k, c), column in parsed.items():
            values[:, k, c] = column * (scale if c >= 3 else 1.0)
        return PrescribedSpec(mask, times, values)

    def equilibrium(self, model, forces, prescribed):
        """`[initial] from = "equilibrium"`: the static equilibrium of the free
        coordinates under gravity and the forces at the start, at rest, held
        constant (with `feedforward = "hold"`, none on the contact bodies), with
        the `[prescribed]` coordinates (without that table, the contact bodies)
        held at their `[initial]` values, or, for a motion from a CSV file, at the
        motion's values at the first time (which the run imposes there); returns
        the initial state and the prescribed motion and forces that start from
        it."""
        n = model.n_bodies
        mask = held_coordinates(n, None if prescribed is None else prescribed.mask)
        y_start = self.y_init
        if prescribed is not None and not prescribed.hold:
            first = prescribed.motion(self.ts).motion(jnp.asarray(self.ts[0]))
            y_start = np.where(mask, np.asarray(first), self.y_init)
        applied = np.array(
            forces_at_start(forces, float(self.ts[0]), jnp.asarray(y_start), n)
        )
        if self.hold_feedforward:
            applied[1:] = 0.0
        try:
            found = equilibrium_start(model, y_start, mask, jnp.asarray(applied))
        except ValueError as err:
            held = "[prescribed] coordinates" if prescribed else "contact bodies"
            self.add(
                "[initial]",
                "from",
                f"no static equilibrium to start from, with the {held} held at "
                f"their [initial] poses: {err}",
            )
            raise ScenarioError(self.source, self.problems.items) from None
        y_init = np.asarray(found.y)
        if prescribed is not None:
            # the free entries of the prescribed motion carry the initial state
            values = np.where(mask, prescribed.values, y_init)
            prescribed = dataclasses.replace(prescribed, values=values)
        if isinstance(forces, PoseTracking):
            # the grasps are tracked from the poses they start at
            forces = eqx.tree_at(lambda f: f.y_ref, forces, jnp.asarray(y_init[1:]))
        return y_init, prescribed, forces

    def identify_spec(self, kind, conns) -> IdentifySpec | None:
        table = self.s.get("identify")
        if table is None or self.names is None:
            return None
        spec = IdentifySpec(
            fit=tuple(table.fit),
            connections=None if table.connections is None else tuple(table.connections),
            axes=None if table.axes is None else tuple(table.axes),
            bodies=None if table.bodies is None else tuple(table.bodies),
            max_iterations=table.max_iterations,
            method=table.method,
            init=table.init,
            initial=table.initial,
            feedforward=table.feedforward,
        )
        labels = conns[1] if conns is not None else ()
        convention = self.model_table.convention if self.model_table else "zxz"
        problems = identify_spec_problems(spec, kind, convention, self.names, labels)
        for key, message in problems:
            self.add("[identify]", key, message)
        return spec

    # -- stage 3: build --------------------------------------------------------------
    def build(self) -> Scenario:
        self.validate_tables()
        self.index = self.names = None
        self.bodies_valid = False
        self.check_bodies()
        self.model_table = self.s.get("model")
        convention = self.model_table.convention if self.model_table else "zxz"
        self.rotation = get_rotation(convention)
        self.coordinate_names = coordinate_names(convention)
        initial = self.poses("initial", rates=True)
        self.y_init, ydot_init = initial if initial is not None else (None, None)
        unloaded = self.poses("unloaded", rates=False)
        if unloaded is None:
            unloaded = self.y_init
        self.ts = self.check_time()
        kind = self.model_table.kind if self.model_table else None
        # Set for the model's kind (a missing one is a problem, raised below).
        conns: Any = None
        matrices: Any = None
        if kind == "mobile":
            if "immobile" in self.raw:
                self.add(
                    "[immobile]",
                    "",
                    "K and D belong to kind = 'immobile'; the mobile model takes "
                    "[[connections]]",
                )
            conns = self.connections(unloaded)
        elif kind == "immobile":
            if "connections" in self.raw:
                self.add(
                    "[[connections]]",
                    "",
                    "connections belong to kind = 'mobile'; the immobile model "
                    "takes K and D in [immobile]",
                )
            if "immobile" not in self.raw:
                self.add(
                    "[immobile]", "", "missing table (K and D) for kind = 'immobile'"
                )
            matrices = self.immobile_matrices()
        forces = self.forces()
        prescribed = self.prescribed()
        identify = self.identify_spec(kind, conns)
        self.problems.raise_if_any()

        bodies = self.rigid_bodies
        gravity = self.model_table.gravity
        model: AbstractElasticModel
        try:
            if kind == "mobile":
                model = MobileModel(bodies, conns[0], gravity, convention)
            else:
                model = ImmobileModel(
                    bodies, matrices["K"], matrices["D"], unloaded, gravity, convention
                )
        except ValueError as err:
            self.add("[model]", "", str(err))
            self.problems.raise_if_any()
        y_init = np.asarray(self.y_init)
        if self.initial_from == "equilibrium":
            y_init, prescribed, forces = self.equilibrium(model, forces, prescribed)
        if self.hold_feedforward:
            hold = holding_forces(model, jnp.asarray(y_init))
            if not np.all(np.isfinite(np.asarray(hold))):
                self.add(
                    "[forces.pose_tracking]",
                    "feedforward",
                    '"hold": the forces that hold the contact bodies at rest in the '
                    "initial state are not finite (check the masses, stiffnesses "
                    "and poses)",
                )
                self.problems.raise_if_any()
            forces = eqx.tree_at(lambda f: f.feedforward, forces, hold)
        solver = self.s.get("solver") or SolverTable()
        source = pathlib.Path(self.source)
        name = self.info.name or source.stem
        return Scenario(
            name=name,
            model=model,
            y_init=jnp.asarray(y_init),
            ydot_init=jnp.asarray(ydot_init),
            ts=jnp.asarray(self.ts),
            forces=forces,
            body_names=tuple(self.names),
            connection_names=conns[1] if conns is not None else (),
            options=SimulationOptions(
                solver.name,
                solver.rtol,
                solver.atol,
                solver.max_steps,
                owner="Scenario",
            ),
            prescribed=prescribed,
            description=self.info.description,
            source=self.source,
            identify=identify,
            initial_from=self.initial_from,
        )


__all__ = ["load_scenario", "build_scenario"]
