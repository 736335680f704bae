"""The scenario file of a fitted model: the original file's tables with the fitted
masses, inertias, stiffnesses and dampings, ready for `elasticoop run`."""

import pathlib
import tomllib

import numpy as np

from .._models import MobileModel
from .toml_text import toml_text


def fitted_scenario_text(scenario, fitted_model, header: str = "") -> str:
    """TOML text of `scenario`'s file (`scenario.source`) with the masses,
    inertias and, for a mobile model, the connections' stiffness and damping of
    `fitted_model`. Paths of data files (`[immobile]` K and D, `[forces]`
    samples, `[prescribed]` motion) become absolute, so the file runs from any
    folder; comments of the original are not kept, `header` comes first."""
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
