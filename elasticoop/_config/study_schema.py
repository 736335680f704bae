"""The study-file schema: one pydantic model per TOML table of a Monte Carlo study
file (see `study_file.load_study`).

Like the scenario tables, every table forbids unknown keys and is strict about
types. Checks against the scenario (a body or connection name, whether a quantity
exists in its model) are made when the study is built.
"""

from typing import Annotated, Literal

from pydantic import (
    ConfigDict,
    Field,
    PlainValidator,
    TypeAdapter,
    ValidationError,
    model_validator,
)

from .._options import MAX_STEPS_LIMIT
from .problems import message_of
from .schema import Fraction, Name, NonNegative, Number, Positive, Table

# The quantities a study may vary, and the outputs it may keep (the names in the
# file; see `study_quantities`).
PARAMETER_QUANTITIES = (
    "mass",
    "inertia",
    "stiffness",
    "damping",
    "rest_length",
    "gravity",
    "kp",
    "kd",
    "lift_height",
    "lift_time",
)
OUTPUT_QUANTITIES = (
    "peak_elastic_force",
    "peak_force_rise",
    "max_deflection",
    "final_pose_error",
    "object_pose",
    "elastic_force",
    "trajectory",
)
DISTRIBUTIONS = ("normal", "lognormal", "uniform")
SEED_LIMIT = 2**32 - 1
Identifier = Annotated[
    str,
    Field(
        pattern=r"^[A-Za-z_][A-Za-z0-9_]*$",
        description="a name in the results: letters, digits and '_'",
    ),
]
_STRICT = ConfigDict(strict=True)  # (as `Table`: no number from a string)
_SPREAD_NUMBER: TypeAdapter = TypeAdapter(NonNegative, config=_STRICT)
_SPREAD_LIST: TypeAdapter = TypeAdapter(
    Annotated[list[NonNegative], Field(min_length=1)], config=_STRICT
)


def _spread(value):
    """A spread: one number for every entry of the quantity, or a list of them.
    Validated as the one or the other by the value's type, so that a problem is
    reported once, by the key's name (a union reports one for each kind)."""
    adapter = _SPREAD_LIST if isinstance(value, list) else _SPREAD_NUMBER
    try:
        return adapter.validate_python(value)
    except ValidationError as err:
        problems = []
        for e in err.errors():
            message = message_of(dict(e))
            index = "".join(f"[{p}]" for p in e["loc"] if isinstance(p, int))
            problems.append(f"entry {index}: {message}" if index else message)
        raise ValueError("; ".join(problems)) from None


Spread = Annotated[float | list[float], PlainValidator(_spread)]


class StudyInfo(Table):
    """Top-level keys: `scenario` (a path relative to the study file, or the name
    of a shipped example), `name` and `description`."""

    scenario: str = Field(min_length=1)
    name: str | None = Field(default=None, min_length=1)
    description: str = ""


class SamplingTable(Table):
    """`[sampling]`: number of samples, seed and method."""

    samples: Annotated[int, Field(ge=1)]
    seed: Annotated[int, Field(ge=0, le=SEED_LIMIT)] = 0
    method: Literal["random", "lhs"] = "random"


class StudyTimeTable(Table):
    """`[time]`: replaces the scenario's time span and output times, key by key."""

    start: Number | None = None
    stop: Number | None = None
    samples: Annotated[int, Field(ge=2)] | None = None


class StudyInitialTable(Table):
    """`[initial]`: what each sample starts from: `from = "equilibrium"` (its own
    rest state, the default) or `"scenario"` (the scenario's initial state)."""

    start: Literal["equilibrium", "scenario"] = Field(
        default="equilibrium", alias="from"
    )


class StudySolverTable(Table):
    """`[solver]`: replaces the scenario's tolerances and step budget, key by key."""

    rtol: Fraction | None = None
    atol: Positive | None = None
    max_steps: Annotated[int, Field(ge=1, le=MAX_STEPS_LIMIT)] | None = None


class ParameterTable(Table):
    """`[[parameters]]`: one uncertain quantity of the scenario and its law."""

    quantity: Literal[PARAMETER_QUANTITIES]  # type: ignore[valid-type]
    name: Identifier | None = None
    bodies: Annotated[list[Name], Field(min_length=1)] | None = None
    connections: Annotated[list[Name], Field(min_length=1)] | None = None
    axes: Annotated[list[str], Field(min_length=1)] | None = None
    distribution: Literal[DISTRIBUTIONS]  # type: ignore[valid-type]
    relative_spread: Spread | None = None
    absolute_spread: Spread | None = None

    @model_validator(mode="after")
    def _one_spread(self):
        given = [
            k
            for k in ("relative_spread", "absolute_spread")
            if getattr(self, k) is not None
        ]
        if len(given) != 1:
            raise ValueError(
                "give exactly one of 'relative_spread' (a fraction of the nominal "
                "value) or 'absolute_spread' (in the quantity's unit)"
            )
        if self.distribution == "lognormal" and self.absolute_spread is not None:
            raise ValueError(
                "a lognormal law takes 'relative_spread' (the standard deviation "
                "of log(value / nominal)), not 'absolute_spread'"
            )
        return self


class OutputTable(Table):
    """`[[outputs]]`: one quantity kept of every sample, and the thresholds whose
    exceedance probabilities the summary reports."""

    quantity: Literal[OUTPUT_QUANTITIES]  # type: ignore[valid-type]
    name: Identifier | None = None
    thresholds: list[Number] = []


class SensitivityTable(Table):
    """`[sensitivity]`: the global sensitivity analysis that `elasticoop
    montecarlo sensitivity` runs: its method, the base points of its design, the
    outputs analysed and the intervals."""

    method: Literal["sobol", "morris", "dgsm"] = "sobol"
    samples: Annotated[int, Field(ge=2, le=2**24)] = 256
    outputs: Annotated[list[Identifier], Field(min_length=1)] | None = None
    second_order: bool = False
    bootstrap: Annotated[int, Field(ge=10, le=100_000)] = 1000
    confidence: Fraction = 0.95
    dgsm_samples: Annotated[int, Field(ge=0, le=2**20)] = 0

    @model_validator(mode="after")
    def _design(self):
        n = self.samples
        if self.method != "morris" and n & (n - 1):
            low = 1 << (n.bit_length() - 1)
            raise ValueError(
                f"samples = {n}: the {self.method} design takes a power of two of "
                f"base points (scrambled Sobol' points keep their balance only "
                f"then), e.g. {low} or {2 * low}"
            )
        if self.second_order and self.method != "sobol":
            raise ValueError("second_order = true needs method = 'sobol'")
        return self


STUDY_SECTIONS = {
    "sampling": (SamplingTable, "table"),
    "initial": (StudyInitialTable, "table"),
    "time": (StudyTimeTable, "table"),
    "solver": (StudySolverTable, "table"),
    "parameters": (ParameterTable, "array"),
    "outputs": (OutputTable, "array"),
    "sensitivity": (SensitivityTable, "table"),
}
STUDY_REQUIRED = ("sampling", "parameters", "outputs")
STUDY_TOP_LEVEL_KEYS = ("scenario", "name", "description")
