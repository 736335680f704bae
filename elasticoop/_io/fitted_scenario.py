"""The scenario file of a fitted model: the original file's tables with the fitted
masses, inertias, stiffnesses and dampings, the applied forces the fit held fixed
and the fit's initial-state rule, ready for `elasticoop run`: it reproduces the
fit's own prediction."""

import pathlib
import tomllib

import numpy as np

from .._models import MobileModel
from .toml_text import toml_text


def fitted_scenario_text(
    scenario,
    fitted_model,
    header: str = "",
    *,
    initial: str = "frozen",
    initial_state=None,
    freeze_feedforward: bool = True,
) -> str:
    """TOML text of `scenario`'s file (`scenario.source`) with the masses,
    inertias and, for a mobile model, the connections' stiffness and damping of
    `fitted_model`. Paths of data files (`[immobile]` K and D, `[forces]`
    samples, `[prescribed]` motion) become absolute, so the file runs from any
    folder; comments of the original are not kept, `header` comes first.

    What the experiment applied is written as the numbers the fit used: a pose
    tracking's feedforward that the scenario derives from its model (`"hold"`,
    `"weight"`) becomes the table of forces of the scenario as loaded (the
    nominal model's), so that it does not change with the fitted values (unless
    `freeze_feedforward` is false: the fit recomputed it as the run does). The
    initial state follows the fit's rule `initial`: `"equilibrium"` keeps
    `[initial] from = "equilibrium"` (the run recomputes the rest state with the
    fitted values, as the fit did); otherwise the `[initial]` tables get the
    numbers of `initial_state`, `(y_init, ydot_init)` (the fit's first
    experiment's), without `from`."""
    if not scenario.source:
        raise ValueError("the scenario was not read from a file (no source)")
    source = pathlib.Path(scenario.source)
    raw = tomllib.loads(source.read_text(encoding="utf-8"))
    base = source.parent

    def absolute(name: str) -> str:
        path = pathlib.Path(name).expanduser()
        return str((path if path.is_absolute() else base / path).resolve())

    mass = np.asarray(fitted_model.bodies.mass, dtype=float)
    inertia = np.asarray(fitted_model.bodies.inertia, dtype=float)
    for k, body in enumerate(raw.get("bodies", [])):
        body["mass"] = float(mass[k])
        body["inertia"] = [float(v) for v in inertia[k]]
    if isinstance(fitted_model, MobileModel):
        stiffness = np.asarray(fitted_model.stiffness, dtype=float)
        damping = np.asarray(fitted_model.damping, dtype=float)
        for k, connection in enumerate(raw.get("connections", [])):
            connection["stiffness"] = [float(v) for v in stiffness[k]]
            connection["damping"] = [float(v) for v in damping[k]]
    pose = raw.get("forces", {}).get("pose_tracking")
    if (
        freeze_feedforward
        and isinstance(pose, dict)
        and pose.get("feedforward", "weight")
        in (
            "hold",
            "weight",
        )
    ):
        feedforward = np.asarray(scenario.forces.feedforward, dtype=float)
        pose["feedforward"] = {
            name: [float(v) for v in row]
            for name, row in zip(scenario.names[1:], feedforward)
        }
    if initial != "equilibrium" and initial_state is not None:
        raw["initial"] = _initial_tables(scenario.names, *initial_state)
    immobile = raw.get("immobile", {})
    for key in ("K", "D"):
        if isinstance(immobile.get(key), str):
            immobile[key] = absolute(immobile[key])
    forces = raw.get("forces", {})
    if isinstance(forces.get("samples"), str):
        forces["samples"] = absolute(forces["samples"])
    motion = raw.get("prescribed", {}).get("motion")
    if isinstance(motion, dict) and isinstance(motion.get("csv"), str):
        motion["csv"] = absolute(motion["csv"])
    return toml_text(raw, header)


def _initial_tables(names, y_init, ydot_init) -> dict:
    """`[initial.<body>]` tables holding the state `(y_init, ydot_init)`."""
    y, ydot = np.asarray(y_init, dtype=float), np.asarray(ydot_init, dtype=float)
    return {
        name: {
            "position": [float(v) for v in y[k, :3]],
            "angles": {"radians": [float(v) for v in y[k, 3:]]},
            "velocity": [float(v) for v in ydot[k, :3]],
            "angle_rates": {"radians": [float(v) for v in ydot[k, 3:]]},
        }
        for k, name in enumerate(names)
    }
