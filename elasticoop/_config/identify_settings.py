"""What `elasticoop identify` fits: the `[identify]` table (or the command-line
options that override it) checked against a scenario, and turned into the
`where` and `mask` arguments of `identify` with readable parameter names."""

import dataclasses
import pathlib
import tomllib
from collections.abc import Callable, Sequence

import numpy as np

from .._models import MobileModel
from .._naming import coordinate_names
from .._scenario import IdentifySpec

INERTIA_AXES = ("A", "B", "C")
_PER_CONNECTION = ("stiffness", "damping")
_PER_BODY = ("mass", "inertia")


def identify_spec_problems(
    spec: IdentifySpec,
    kind: str | None,
    convention: str,
    bodies: Sequence[str],
    connections: Sequence[str],
    check_applicable: bool = True,
) -> list[tuple[str, str]]:
    """`(key, message)` for every name of `spec` the scenario does not have (and,
    with `check_applicable`, for a key that applies to no fitted quantity)."""
    out = []
    per_connection = [q for q in spec.fit if q in _PER_CONNECTION]
    if per_connection and kind == "immobile":
        out.append(
            (
                "fit",
                f"{' and '.join(per_connection)} can be fitted for the mobile model's "
                f"[[connections]] only (an immobile model's K and D are matrices)",
            )
        )
    if spec.connections is not None:
        if check_applicable and not per_connection:
            out.append(("connections", "applies to fitting stiffness or damping only"))
        for name in spec.connections:
            if name not in connections:
                out.append(
                    (
                        "connections",
                        f"no connection named '{name}' (connections: "
                        f"{', '.join(connections) or 'none'})",
                    )
                )
    if spec.axes is not None:
        if check_applicable and not per_connection:
            out.append(("axes", "applies to fitting stiffness or damping only"))
        coords = coordinate_names(convention)
        for name in spec.axes:
            if name not in coords:
                out.append(
                    (
                        "axes",
                        f"unknown axis '{name}' (with convention '{convention}': "
                        f"{', '.join(coords)})",
                    )
                )
    if spec.bodies is not None:
        if check_applicable and not any(q in _PER_BODY for q in spec.fit):
            out.append(("bodies", "applies to fitting mass or inertia only"))
        for name in spec.bodies:
            if name not in bodies:
                out.append(
                    ("bodies", f"no body named '{name}' (bodies: {', '.join(bodies)})")
                )
    for key in ("fit", "connections", "axes", "bodies"):
        values = getattr(spec, key)
        if values is not None and len(set(values)) != len(values):
            out.append((key, f"names a value twice: {list(values)}"))
    return out


@dataclasses.dataclass(frozen=True)
class FitSelection:
    """The free parameters of a fit: `where` and `mask` for `identify`, and one
    readable name per free entry in `identify`'s order (e.g.
    `stiffness[plate-front].x`, `mass[plate]`, `inertia[plate].A`)."""

    where: Callable
    mask: tuple
    names: tuple[str, ...]
    quantities: tuple[str, ...]


def fit_selection(scenario, spec: IdentifySpec) -> FitSelection:
    """The `FitSelection` of `spec` (checked with `identify_spec_problems`) for
    `scenario`'s model."""
    model = scenario.model
    coords = coordinate_names(model.convention)
    quantities = tuple(q for q in (*_PER_CONNECTION, *_PER_BODY) if q in spec.fit)
    bodies = list(scenario.names)
    connections = list(scenario.connection_names)
    if not connections and isinstance(model, MobileModel):
        pairs = np.asarray(model.pairs).tolist()
        connections = [f"{bodies[i]}-{bodies[j]}" for i, j in pairs]
    leaves, masks, names = [], [], []
    mask: np.ndarray
    labels: list
    for q in quantities:
        if q in _PER_CONNECTION:
            rows = [
                k
                for k, c in enumerate(connections)
                if spec.connections is None or c in spec.connections
            ]
            cols = [
                k for k, c in enumerate(coords) if spec.axes is None or c in spec.axes
            ]
            mask = np.zeros((len(connections), 6), bool)
            mask[np.ix_(rows, cols)] = True
            labels = [[f"{q}[{c}].{a}" for a in coords] for c in connections]
        else:
            rows = [
                k
                for k, b in enumerate(bodies)
                if spec.bodies is None or b in spec.bodies
            ]
            if q == "mass":
                mask = np.zeros(len(bodies), bool)
                mask[rows] = True
                labels = [f"mass[{b}]" for b in bodies]
            else:
                mask = np.zeros((len(bodies), 3), bool)
                mask[rows] = True
                labels = [[f"inertia[{b}].{a}" for a in INERTIA_AXES] for b in bodies]
        leaves.append(q)
        masks.append(mask)
        names += [n for n, on in zip(np.ravel(labels), mask.reshape(-1)) if on]

    def where(m):
        return tuple(_leaf(m, q) for q in leaves)

    return FitSelection(where, tuple(masks), tuple(str(n) for n in names), quantities)


def _leaf(model, quantity):
    if quantity == "mass":
        return model.bodies.mass
    if quantity == "inertia":
        return model.bodies.inertia
    return getattr(model, quantity)


def derived_feedforward(scenario) -> str | None:
    """The pose tracking's `feedforward` rule (`"hold"`, `"weight"`) when the
    scenario derives the feedforward from its model, else `None` (read from the
    scenario's file)."""
    if not scenario.source:
        return None
    try:
        raw = tomllib.loads(pathlib.Path(scenario.source).read_text(encoding="utf-8"))
    except (OSError, tomllib.TOMLDecodeError):
        return None
    pose = raw.get("forces", {}).get("pose_tracking")
    if not isinstance(pose, dict):
        return None
    rule = pose.get("feedforward", "weight")
    return rule if rule in ("hold", "weight") else None
