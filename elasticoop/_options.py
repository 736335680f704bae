"""`SimulationOptions`: how a run is integrated (solver, tolerances, step budget and
the thresholds of the two singularities), checked once for every caller."""

import dataclasses
import math
import numbers
import sys
import warnings
from typing import TYPE_CHECKING, Any

import equinox as eqx
import numpy as np

if TYPE_CHECKING:
    import diffrax

    Solver = diffrax.AbstractSolver
else:  # diffrax is imported when a run needs it (runtime checks see `Any`)
    Solver = Any

# Solver names of scenario files and the command line -> the names of the diffrax
# solvers (imported when a run needs one: checking a scenario does not import
# diffrax).
SOLVERS = {
    "tsit5": "Tsit5",
    "dopri5": "Dopri5",
    "dopri8": "Dopri8",
    "bosh3": "Bosh3",
    "heun": "Heun",
    "kvaerno3": "Kvaerno3",
    "kvaerno5": "Kvaerno5",
}

# The default solver and tolerances (`SimulationOptions`).
DEFAULT_SOLVER = "dopri8"
DEFAULT_RTOL = 1e-9
DEFAULT_ATOL = 1e-11

# Documented thresholds of the two singularities a run stops at.
GIMBAL_TOL = 1e-3  # |sin theta| (ZXZ) or |cos pitch| (RPY)
LINK_TOL = 1e-3  # |r_i - r_j| relative to the rest length rho_0

# The largest step budget: the number of steps taken is reported as a 32-bit
# integer (`Trajectory.n_steps`).
MAX_STEPS_LIMIT = 2**31 - 1


def _positive(value, name: str, owner: str) -> float:
    try:
        # (text and booleans are not numbers here, though float() reads them)
        if isinstance(value, str | bytes | bool | np.bool_):
            raise TypeError
        number = float(value)
    except (TypeError, ValueError, OverflowError):
        number = math.nan
    if not (math.isfinite(number) and number > 0):
        shown = (
            _show_integer(value)
            if isinstance(value, numbers.Integral) and not isinstance(value, bool)
            else repr(value)
        )
        raise ValueError(f"{owner}.{name} must be a positive number, got {shown}")
    return number


def check_initial_step(dt0, owner: str) -> None:
    """Refuse an initial step `dt0` that is not `None` or a positive number."""
    if dt0 is not None:
        _positive(dt0, "dt0", owner)


def _show_integer(value: numbers.Integral) -> str:
    """An integer as written, or its sign and number of digits when it is long."""
    text = str(int(value))
    digits = len(text.lstrip("-"))
    if digits <= 24:
        return text
    return f"{'a negative' if value < 0 else 'an'} integer of {digits} digits"


def _is_diffrax_solver(solver: Any) -> bool:
    """Whether `solver` is a diffrax solver (without importing diffrax for an object
    that cannot be one: diffrax defines its solvers' classes)."""
    if "diffrax" not in sys.modules:
        return False
    import diffrax

    return isinstance(solver, diffrax.AbstractSolver)


class SimulationOptions(eqx.Module):
    """The settings of `simulate` that are not physics, validated in one place and
    hashable by value (a `jit` key: equal options share compiled code).

    **Fields:**

    - `solver`: a diffrax solver, or its name in `SOLVERS` (`"tsit5"`, `"dopri5"`,
      `"dopri8"`, the default, `"bosh3"`, `"heun"`, `"kvaerno3"`, `"kvaerno5"`).
    - `rtol`, `atol`: tolerances of the adaptive step-size controller (> 0;
      `rtol` < 1; default 1e-9 and 1e-11).

    The default solver and tolerances are those of the least work at the accuracy
    of SciPy's `solve_ivp` (DOP853, rtol 1e-8, atol 1e-10) on the three-body lift
    (`benchmarks/work_precision.py`, `benchmarks/montecarlo.py`: Dopri8 at rtol
    1e-8 is less accurate than that, at 1e-9 more; Tsit5 needs more steps for the
    same error).
    - `max_steps`: the most solver steps a run may take, an integer from 1 to
      `MAX_STEPS_LIMIT` ($2^{31} - 1$).
    - `gimbal_tol`: a run stops when a body's $|\\sin\\theta|$ (ZXZ) or
      $|\\cos(\\text{pitch})|$ (RPY) falls below this (in (0, 1)).
    - `link_tol`: a run stops when a link of rest length $\\rho_0 > 0$ shrinks to
      $|r_i - r_j| <$ `link_tol` $\\rho_0$ (in (0, 1)).
    - `owner`: the name used in error messages (`"SimulationOptions"`, or where
      a function builds the options from its own keywords, `"simulate"`,
      `"Study"`, ...).
    """

    solver: Solver | str = eqx.field(static=True, default=DEFAULT_SOLVER)
    rtol: float = eqx.field(static=True, default=DEFAULT_RTOL)
    atol: float = eqx.field(static=True, default=DEFAULT_ATOL)
    max_steps: int = eqx.field(static=True, default=100_000)
    gimbal_tol: float = eqx.field(static=True, default=GIMBAL_TOL)
    link_tol: float = eqx.field(static=True, default=LINK_TOL)
    owner: str = eqx.field(static=True, default="SimulationOptions", compare=False)

    def __check_init__(self):
        if isinstance(self.solver, str):
            if self.solver not in SOLVERS:
                raise ValueError(
                    f"{self.owner}.solver must be one of {sorted(SOLVERS)}, got "
                    f"{self.solver!r}"
                )
        elif not _is_diffrax_solver(self.solver):
            raise ValueError(
                f"{self.owner}.solver must be a diffrax solver or one of "
                f"{sorted(SOLVERS)}, got {self.solver!r}"
            )
        for name in ("rtol", "atol", "gimbal_tol", "link_tol"):
            _positive(getattr(self, name), name, self.owner)
        # Fractions: |sin theta| and |cos pitch| are at most 1, and a link at or
        # below `link_tol` x its rest length counts as collapsed.
        for name, meaning in (
            ("rtol", "a relative error"),
            ("gimbal_tol", "a threshold on |sin theta| or |cos pitch|"),
            ("link_tol", "a fraction of the rest length"),
        ):
            value = float(getattr(self, name))
            if not value < 1:
                raise ValueError(
                    f"{self.owner}.{name} must be below 1 ({meaning}), got {value!r}"
                )
        steps = self.max_steps
        if isinstance(steps, bool) or not isinstance(steps, numbers.Integral):
            raise ValueError(
                f"{self.owner}.max_steps must be a positive integer, got {steps!r}"
            )
        if not 1 <= steps <= MAX_STEPS_LIMIT:
            raise ValueError(
                f"{self.owner}.max_steps must be a positive integer of at most "
                f"{MAX_STEPS_LIMIT}, got {_show_integer(steps)}"
            )

    @property
    def solver_name(self) -> str:
        """The solver's name (`"tsit5"`, ... or the diffrax class name)."""
        if isinstance(self.solver, str):
            return self.solver
        return type(self.solver).__name__

    def diffrax_solver(self) -> Solver:
        """The diffrax solver instance."""
        if isinstance(self.solver, str):
            import diffrax

            return getattr(diffrax, SOLVERS[self.solver])()
        return self.solver

    def kwargs(self) -> dict[str, Any]:
        """The keyword arguments of `simulate` these options stand for
        (`{"options": self}`)."""
        return dict(options=self)


# The fields of `SimulationOptions` that `simulate` and `Scenario` also took one by
# one (deprecated spellings).
OPTION_FIELDS = ("solver", "rtol", "atol", "max_steps", "gimbal_tol", "link_tol")


def resolve_options(options: Any, owner: str, **fields: Any) -> SimulationOptions:
    """`options` (a `SimulationOptions`, checked here; default
    `SimulationOptions()`), with the fields given one by one
    in `fields` (those not `None`) in their place, each with a
    `DeprecationWarning`: the deprecated spellings of `simulate(..., rtol=...)`."""
    if options is not None and not isinstance(options, SimulationOptions):
        raise ValueError(
            f"{owner}.options must be a SimulationOptions, got {type(options).__name__}"
        )
    given = {name: value for name, value in fields.items() if value is not None}
    if given:
        shown = ", ".join(f"{name}={value!r}" for name, value in given.items())
        warnings.warn(
            f"{owner}({', '.join(given)}=...) is deprecated: pass "
            f"options=SimulationOptions({shown})",
            DeprecationWarning,
            stacklevel=3,
        )
    if options is None:
        return SimulationOptions(**given, owner=owner)
    if not given:
        return options
    return dataclasses.replace(options, **given, owner=owner)
