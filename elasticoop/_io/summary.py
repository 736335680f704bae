"""A run in a few numbers: a JSON-ready summary and its text form."""

import numpy as np

from .._models import MobileModel
from .._naming import (
    body_names as body_names_of,
    connection_names as connection_names_of,
)
from .._status import status_message
from .grasp_peaks import peak_grasp_loads


def summarize(traj, body_names=None, connection_names=None) -> dict:
    """A JSON-ready summary of a trajectory: object displacement and rotation, peak
    grasp force and torque, elastic plus damping, per connection (`MobileModel`) or
    per contact body (`ImmobileModel`), over the run (at the saved samples and
    between them: `peak_grasp_loads`), and the energy balance
    $\\Delta(T + \\Pi + \\sum m g z) = W_F - E_{diss}$ with its residual, also
    relative to the largest term of the balance ($|W_F|$, $E_{diss}$,
    $|\\Delta T|$, $|\\Delta \\Pi|$, $|\\Delta \\sum m g z|$)."""
    model = traj.model
    n = model.n_bodies
    bodies = body_names_of(body_names, n)
    y = np.asarray(traj.y)
    last = int(np.max(np.nonzero(np.all(np.isfinite(y), axis=(1, 2)))[0], initial=0))
    kinetic = np.asarray(traj.kinetic_energy())
    elastic = np.asarray(traj.elastic_energy())
    gravity = np.asarray(traj.gravity_energy())
    work = float(traj.work[last])
    dissipated = float(traj.dissipated[last])
    change = (kinetic[last] + elastic[last] + gravity[last]) - (
        kinetic[0] + elastic[0] + gravity[0]
    )
    residual = change - work + dissipated
    # The residual relative to the largest term of the balance: each energy's
    # change, the work and the dissipated energy (a body falling freely trades
    # kinetic for gravity energy with no work: its total change is round-off).
    terms = (
        work,
        dissipated,
        kinetic[last] - kinetic[0],
        elastic[last] - elastic[0],
        gravity[last] - gravity[0],
    )
    scale = max(max(abs(float(term)) for term in terms), 1e-300)
    pairs, _ = traj.grasp_loads()
    # elastic + damping, between the saved samples too
    peak_force, peak_torque = peak_grasp_loads(traj)
    if isinstance(model, MobileModel):
        labels = list(connection_names_of(connection_names, pairs, bodies))
        peak_of = "connection"
    else:
        labels = list(bodies[1:])
        peak_of = "contact body"
    links = labels if isinstance(model, MobileModel) else None
    return {
        "status": int(traj.status),
        "message": status_message(traj, bodies, links),
        "model": type(model).__name__,
        "convention": model.convention,
        "bodies": list(bodies),
        "simulated_time": float(traj.ts[last] - traj.ts[0]),
        "object_displacement": (y[last, 0, :3] - y[0, 0, :3]).tolist(),
        "object_rotation": (y[last, 0, 3:] - y[0, 0, 3:]).tolist(),
        "peak_of": peak_of,
        "peak_labels": labels,
        "peak_force": peak_force.tolist(),
        "peak_torque": peak_torque.tolist(),
        "energy": {
            "kinetic_final": float(kinetic[last]),
            "elastic_final": float(elastic[last]),
            "kinetic_change": float(kinetic[last] - kinetic[0]),
            "elastic_change": float(elastic[last] - elastic[0]),
            "gravity_change": float(gravity[last] - gravity[0]),
            "total_change": float(change),
            "work_of_forces": work,
            "dissipated": dissipated,
            "residual": float(residual),
            "relative_residual": float(abs(residual) / scale),
        },
        "pairs": [list(p) for p in pairs],
    }


def scenario_summary(scenario, traj, wall_time=None) -> dict:
    """`summarize` for a run of a `Scenario`, with the scenario's name, file,
    solver settings and the wall time [s] (compilation included)."""
    summary = {
        "scenario": scenario.name,
        "scenario_file": scenario.source,
        "solver": {
            "name": scenario.solver,
            "rtol": scenario.rtol,
            "atol": scenario.atol,
            "max_steps": scenario.max_steps,
        },
        "wall_time": wall_time,
    }
    summary.update(summarize(traj, scenario.names, scenario.connection_names or None))
    return summary


def format_summary(s: dict) -> str:
    """The summary of a run (see `summarize`) as text."""
    e = s["energy"]
    dx, dy, dz = s["object_displacement"]
    n_links = len(s["peak_labels"])
    links = (
        f"{n_links} elastic grasp{'s' if n_links != 1 else ''}"
        if s["model"] == "MobileModel"
        else f"{n_links} contact bod{'ies' if n_links != 1 else 'y'}"
    )
    lines = [
        f"elasticoop: {s.get('scenario', 'trajectory')} ({s['model']}, "
        f"{len(s['bodies'])} bodies, {links})",
    ]
    if s.get("wall_time") is not None:
        lines.append(
            f"  simulated {s['simulated_time']:.2f} s in {s['wall_time']:.2f} s wall "
            "(compilation included)"
        )
    if s["status"] != 0:
        lines.append(f"  STOPPED EARLY: {s['message']}")
    lines += [
        f"  object displacement: dx = {dx:+.5f} m, dy = {dy:+.5f} m, dz = {dz:+.5f} m",
        "  object rotation (Euler angles): "
        + ", ".join(f"{a:+.2e}" for a in s["object_rotation"])
        + " rad",
        "  peak grasp load (elastic + damping):",
    ]
    for (i, j), label, f, t in zip(
        s["pairs"], s["peak_labels"], s["peak_force"], s["peak_torque"]
    ):
        lines.append(
            f"    grasp {j} ({label}): |force| {f:8.3f} N, |torque| {t:.4f} N m"
        )
    lines += [
        "  energy balance [J]:",
        f"    work of manipulator forces  {e['work_of_forces']:+.6f}",
        f"    dissipated in the grasps    {e['dissipated']:+.6f}",
        f"    change of T + Pi + m g z    {e['total_change']:+.6f}"
        f"  (kinetic {e['kinetic_change']:+.6f}, elastic {e['elastic_change']:+.6f},"
        f" gravity {e['gravity_change']:+.6f})",
        f"    residual (change - work + dissipated) {e['residual']:+.2e}"
        f"  (relative {e['relative_residual']:.1e})",
    ]
    return "\n".join(lines)
