"""The scenario-file schema: one pydantic model per TOML table.

Every table forbids unknown keys and is strict about types (an integer is accepted
where a number is expected, nothing else is converted). Checks that need more than
one table (a connection naming a body, a CSV column naming a coordinate) are done
when the scenario is built (`elasticoop._config.build`).
"""

import math
from typing import Annotated, Any, Literal, get_args

from pydantic import (
    AfterValidator,
    BaseModel,
    BeforeValidator,
    ConfigDict,
    Field,
    model_validator,
)

from .._options import (
    DEFAULT_ATOL,
    DEFAULT_RTOL,
    DEFAULT_SOLVER,
    MAX_STEPS_LIMIT,
    SOLVERS as SOLVER_CLASSES,
)
from .limits import magnitude_problem


def _bounded(value: float) -> float:
    """A number of at most `limits.MAX_MAGNITUDE` in magnitude."""
    problem = magnitude_problem(value)
    if problem:
        raise ValueError(problem)
    return value


Bounded = AfterValidator(_bounded)
Number = Annotated[float, Field(allow_inf_nan=False), Bounded]
Positive = Annotated[float, Field(gt=0, allow_inf_nan=False), Bounded]
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False), Bounded]
Fraction = Annotated[float, Field(gt=0, lt=1, allow_inf_nan=False)]  # in (0, 1)
Vector3 = Annotated[list[Number], Field(min_length=3, max_length=3)]
Vector6 = Annotated[list[Number], Field(min_length=6, max_length=6)]
NonNegative6 = Annotated[list[NonNegative], Field(min_length=6, max_length=6)]
# Body names appear in CSV headers as "<body>.<column>", hence no dots or spaces.
Name = Annotated[
    str,
    Field(
        pattern=r"^[A-Za-z_][A-Za-z0-9_\-]*$",
        description="a body name: letters, digits, '_' and '-', no spaces or dots",
    ),
]
AngleUnit = Literal["degrees", "radians"]

SOLVERS = tuple(SOLVER_CLASSES)


class Table(BaseModel):
    model_config = ConfigDict(extra="forbid", strict=True)


def _angle_unit_stated(value):
    if isinstance(value, list):
        raise ValueError(
            "angles need a stated unit: write { degrees = [a1, a2, a3] } or "
            "{ radians = [a1, a2, a3] }"
        )
    if isinstance(value, dict):
        unknown = set(value) - {"degrees", "radians"}
        if unknown:
            raise ValueError(
                f"unknown angle unit {sorted(unknown)[0]!r}: use 'degrees' or 'radians'"
            )
        if len(value) != 1:
            raise ValueError("give the angles in exactly one unit, degrees or radians")
    return value


class _Angles(Table):
    degrees: Vector3 | None = None
    radians: Vector3 | None = None

    def to_radians(self) -> list[float]:
        if self.radians is not None:
            return list(self.radians)
        # one of the two is given (checked when the table is read)
        return [math.radians(a) for a in self.degrees]  # type: ignore[union-attr]


Angles = Annotated[_Angles, BeforeValidator(_angle_unit_stated)]
OptionalAngles = Annotated[_Angles | None, BeforeValidator(_angle_unit_stated)]


def _matrix(value):
    """A matrix inline (rows of numbers) or the path of a .npy or .csv file."""
    if isinstance(value, str):
        return value
    if not isinstance(value, list) or not all(isinstance(r, list) for r in value):
        raise ValueError(
            "give a matrix as rows of numbers ([[...], [...]]) or a .npy/.csv path"
        )
    for r, row in enumerate(value):
        for c, entry in enumerate(row):
            ok = isinstance(entry, int | float) and not isinstance(entry, bool)
            if ok and isinstance(entry, int) and abs(entry) >= 2**1024:
                raise ValueError(
                    f"entry [{r}][{c}] must be a finite number, got an integer of "
                    f"{len(str(abs(entry)))} digits (beyond float64's range)"
                )
            if not ok or not math.isfinite(entry):
                raise ValueError(
                    f"entry [{r}][{c}] must be a finite number, got {entry!r}"
                )
            problem = magnitude_problem(float(entry))
            if problem:
                raise ValueError(f"entry [{r}][{c}]: {problem}")
    return value


Matrix = Annotated[Any, BeforeValidator(_matrix)]


def _coordinate_list(value):
    if value == "all":
        return ["all"]
    if not isinstance(value, list) or not all(isinstance(v, str) for v in value):
        raise ValueError('give a list of coordinate names (e.g. ["x", "z"]) or "all"')
    return value


def _motion(value):
    if value == "hold":
        return None
    if isinstance(value, str):
        raise ValueError(
            f'motion must be "hold" or {{ csv = "FILE", angle_unit = ... }}, '
            f"got {value!r}"
        )
    return value


def _text(allowed: str):
    """A validator of text without control characters other than `allowed` (a NUL
    cannot be stored in the netCDF file's attributes, and the others garble
    the reports)."""

    def check(value: str) -> str:
        bad = sorted({f"U+{ord(ch):04X}" for ch in value if _control(ch, allowed)})
        if bad:
            raise ValueError(
                f"holds control characters ({', '.join(bad)}), got {value[:40]!r}"
                + ("..." if len(value) > 40 else "")
            )
        return value

    return AfterValidator(check)


def _control(ch: str, allowed: str) -> bool:
    return ch not in allowed and (ord(ch) < 32 or 0x7F <= ord(ch) < 0xA0)


class ScenarioInfo(Table):
    """Top-level keys: `name` (default: the file name) and `description` (text
    without control characters; the description may hold line breaks and
    tabs)."""

    name: Annotated[str, _text("")] | None = Field(default=None, min_length=1)
    description: Annotated[str, _text("\n\t\r")] = ""


class ModelTable(Table):
    """`[model]`: which appendix, Euler convention and gravity."""

    kind: Literal["mobile", "immobile"]
    convention: Literal["zxz", "rpy"] = "zxz"
    gravity: NonNegative = 9.81


class BodyTable(Table):
    """`[[bodies]]`: one rigid body; the first one is the manipulated object."""

    name: Name
    mass: Positive
    inertia: Annotated[list[Positive], Field(min_length=3, max_length=3)]


class PoseTable(Table):
    """`[unloaded.<body>]`: a pose, position [m] and Euler angles (unit stated)."""

    position: Vector3
    angles: Angles


class InitialTable(PoseTable):
    """`[initial.<body>]`: pose and rates (velocity [m/s], angle rates per s)."""

    velocity: Vector3 = [0.0, 0.0, 0.0]
    angle_rates: OptionalAngles = None


class ConnectionTable(Table):
    """`[[connections]]`: one elastic link of the mobile model (Appendix B)."""

    bodies: Annotated[list[Name], Field(min_length=2, max_length=2)]
    stiffness: NonNegative6
    damping: NonNegative6
    rest_length: NonNegative | None = None
    rest_angles: OptionalAngles = None
    name: Name | None = None


class ImmobileTable(Table):
    """`[immobile]`: stiffness K and damping D of Appendix A, (6m+6) x (6m+6)."""

    K: Matrix
    D: Matrix


FeedforwardWord = Literal["weight", "hold", "none"]
_FEEDFORWARD_WORDS = get_args(FeedforwardWord)


def _feedforward_word(value: Any) -> Any:
    """One message for a feedforward that is neither a word it knows nor a table
    (instead of one for each form it could have taken)."""
    if isinstance(value, dict):
        return value
    if value in _FEEDFORWARD_WORDS:
        return value
    words = ", ".join(repr(w) for w in _FEEDFORWARD_WORDS)
    raise ValueError(
        f"must be one of {words} or a table of six numbers by contact-body name, "
        f"got {value!r}"
    )


class PoseTrackingTable(Table):
    """`[forces.pose_tracking]`: PD control of the grasp poses along a lift, plus a
    constant feedforward: `"weight"` (an equal share of the total weight on each
    grasp, along z), `"hold"` (the forces that hold each contact body at rest in
    the initial state, $\\partial\\Pi/\\partial Y_i - G_i$), `"none"`, or the
    numbers themselves: a table of generalized forces by contact-body name (six
    numbers each, forces [N] then generalized torques [N m]; a body left out gets
    none), as `elasticoop identify` writes the feedforward it held fixed."""

    lift_height: Number
    lift_time: Positive
    kp: NonNegative6
    kd: NonNegative6
    feedforward: Annotated[
        FeedforwardWord | dict[Name, Vector6],
        BeforeValidator(_feedforward_word),
    ] = "weight"


class ForcesTable(Table):
    """`[forces]`: exactly one of `constant`, `samples`, `pose_tracking`."""

    constant: dict[Name, Vector6] | None = None
    samples: str | None = None
    pose_tracking: PoseTrackingTable | None = None

    @model_validator(mode="after")
    def _one_kind(self):
        given = [
            k for k in ("constant", "samples", "pose_tracking") if getattr(self, k)
        ]
        if len(given) != 1:
            raise ValueError(
                "give exactly one of 'constant', 'samples' or 'pose_tracking'"
                + (f" (got {', '.join(given)})" if given else "")
            )
        return self


class TimeTable(Table):
    """`[time]`: time span [s] and the number of evenly spaced output samples (at
    least 2; the results they make must fit `limits.MAX_OUTPUT_BYTES`, checked when
    the scenario is built)."""

    start: Number = 0.0
    stop: Number
    samples: Annotated[int, Field(ge=2)] = 101


class SolverTable(Table):
    """`[solver]`: diffrax solver by name, the step-size controller's tolerances and
    the step budget (an integer from 1 to `MAX_STEPS_LIMIT`); by default those of
    `SimulationOptions()`, as `simulate` without options."""

    name: Literal[SOLVERS] = DEFAULT_SOLVER  # type: ignore[valid-type]  # the names
    rtol: Fraction = DEFAULT_RTOL
    atol: Positive = DEFAULT_ATOL
    max_steps: Annotated[int, Field(ge=1, le=MAX_STEPS_LIMIT)] = 100_000


class MotionCsv(Table):
    csv: str
    angle_unit: AngleUnit


class PrescribedTable(Table):
    """`[prescribed]`: coordinates given as functions of time."""

    coordinates: dict[Name, Annotated[list[str], BeforeValidator(_coordinate_list)]] = (
        Field(min_length=1)
    )
    # None: "hold" (keep the initial value)
    motion: Annotated[MotionCsv | None, BeforeValidator(_motion)] = None


FITTED_QUANTITIES = ("stiffness", "damping", "mass", "inertia")
IDENTIFY_METHODS = ("levenberg-marquardt", "lbfgs")
# How `elasticoop identify` sets each experiment's initial state (see `identify`'s
# `initial`); default: "equilibrium" for `[initial] from = "equilibrium"`, else
# "frozen".
INITIAL_RULES = ("equilibrium", "frozen", "data", "fitted")


class IdentifyTable(Table):
    """`[identify]`: what `elasticoop identify` fits, and how (command-line options
    override each key). Names are checked against the scenario when it is built."""

    fit: Annotated[list[Literal[FITTED_QUANTITIES]], Field(min_length=1)] = [  # type: ignore[valid-type]
        "stiffness",
        "damping",
    ]
    connections: Annotated[list[str], Field(min_length=1)] | None = None
    axes: Annotated[list[str], Field(min_length=1)] | None = None
    bodies: Annotated[list[Name], Field(min_length=1)] | None = None
    max_iterations: Annotated[int, Field(ge=1, le=100_000)] = 100
    method: Literal[IDENTIFY_METHODS] = "levenberg-marquardt"  # type: ignore[valid-type]
    init: Literal["equation_error", "model"] = "equation_error"
    initial: Literal[INITIAL_RULES] | None = None  # type: ignore[valid-type]
    feedforward: Literal["auto", "frozen", "rest"] = "auto"


# Top-level layout: table name -> (schema, shape): "table", "array" (array of
# tables) or "by_body" (a table of tables keyed by body name).
SECTIONS = {
    "model": (ModelTable, "table"),
    "bodies": (BodyTable, "array"),
    "connections": (ConnectionTable, "array"),
    "immobile": (ImmobileTable, "table"),
    "initial": (InitialTable, "by_body"),
    "unloaded": (PoseTable, "by_body"),
    "forces": (ForcesTable, "table"),
    "prescribed": (PrescribedTable, "table"),
    "time": (TimeTable, "table"),
    "solver": (SolverTable, "table"),
    "identify": (IdentifyTable, "table"),
}
REQUIRED = ("model", "bodies", "initial", "time")
TOP_LEVEL_KEYS = ("name", "description")
