"""Names of bodies and coordinates: the one vocabulary of exports, Monte Carlo
studies, identification reports and analyses.

Body 0 is the object, bodies 1..m the contact bodies; the default names are
`object, contact1, ..., contactm`. Coordinate $k$ of a body is `x, y, z` followed by
the convention's Euler angles (`psi, theta, phi` for ZXZ, `roll, pitch, yaw` for
RPY), and a degree of freedom of the stacked $Y$ is named `<body>.<coordinate>`.
"""

from collections.abc import Iterable, Sequence

import numpy as np

TRANSLATION_NAMES = ("x", "y", "z")
ANGLE_NAMES = {"zxz": ("psi", "theta", "phi"), "rpy": ("roll", "pitch", "yaw")}


def default_body_names(n_bodies: int) -> tuple[str, ...]:
    """`("object", "contact1", ..., "contact<m>")` for `n_bodies = m + 1`."""
    return ("object",) + tuple(f"contact{i}" for i in range(1, n_bodies))


def distinct_names(given: Iterable | None, n: int, default, what: str):
    """`given` as a tuple of `n` distinct strings (`default` when `None`)."""
    if given is None:
        return tuple(default)
    if isinstance(given, str):  # (its letters would be taken for the names)
        raise ValueError(
            f"{what} must be a list of {n} names, got the single string {given!r}"
        )
    names = tuple(str(b) for b in given)
    if len(names) != n or len(set(names)) != n:
        raise ValueError(f"{what} must be {n} distinct names, got {list(given)}")
    return names


def body_names(given: Iterable | None, n_bodies: int) -> tuple[str, ...]:
    """Validated body names, or the defaults."""
    return distinct_names(given, n_bodies, default_body_names(n_bodies), "body_names")


def coordinate_names(convention: str) -> tuple[str, ...]:
    """`("x", "y", "z")` followed by the convention's angle names."""
    try:
        angles = ANGLE_NAMES[convention]
    except (KeyError, TypeError):
        raise ValueError(
            f"convention must be one of {sorted(ANGLE_NAMES)}, got {convention!r}"
        ) from None
    return TRANSLATION_NAMES + angles


def dof_names(bodies: Sequence[str], convention: str) -> list[str]:
    """`<body>.<coordinate>` for every entry of the stacked $Y$, body-major."""
    return [f"{b}.{c}" for b in bodies for c in coordinate_names(convention)]


def connection_names(
    given: Iterable | None,
    pairs: Sequence[tuple[int, int]] | np.ndarray,
    bodies: Sequence[str],
) -> tuple[str, ...]:
    """Validated connection names, or `<body_i>-<body_j>` per pair `(i, j)`."""
    pairs = [(int(i), int(j)) for i, j in pairs]
    default = tuple(f"{bodies[i]}-{bodies[j]}" for i, j in pairs)
    return distinct_names(given, len(pairs), default, "connection_names")


# The time series of a run's results besides `y` and `ydot`, the variables of
# `trajectory_to_xarray` and the column prefixes of `elasticoop run`'s
# trajectory.csv (derived from the motion: not measured data).
RESULT_SERIES = (
    "kinetic_energy",
    "elastic_energy",
    "gravity_energy",
    "work",
    "dissipated",
    "energy_residual",
    "elastic_force",
    "elastic_wrench",
    "reaction",
    "applied_force",
)
