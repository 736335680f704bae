"""The main job: simulate the built-in scenario and print a readable summary."""

import argparse
import sys
import time

import numpy as np

from ._scenario import default_scenario
from ._simulate import SimulationError, simulate


def run_default(rtol: float = 1e-8, atol: float = 1e-10) -> dict:
    """Simulate `default_scenario()` and return its summary as a dict."""
    scenario = default_scenario()
    start = time.perf_counter()
    traj = simulate(
        scenario.model,
        scenario.y_init,
        scenario.ydot_init,
        scenario.ts,
        forces=scenario.forces,
        rtol=rtol,
        atol=atol,
    )
    traj.y.block_until_ready()
    wall = time.perf_counter() - start

    y = np.asarray(traj.y)
    wrench = np.asarray(traj.elastic_wrench())  # (times, connections, 6)
    kinetic = np.asarray(traj.kinetic_energy())
    elastic = np.asarray(traj.elastic_energy())
    gravity = np.asarray(traj.gravity_energy())
    work = float(traj.work[-1])
    dissipated = float(traj.dissipated[-1])
    change = (kinetic[-1] + elastic[-1] + gravity[-1]) - (
        kinetic[0] + elastic[0] + gravity[0]
    )
    residual = change - work + dissipated
    return {
        "scenario": scenario.name,
        "simulated_time": float(traj.ts[-1] - traj.ts[0]),
        "wall_time": wall,
        "object_displacement": (y[-1, 0, :3] - y[0, 0, :3]).tolist(),
        "object_rotation": (y[-1, 0, 3:] - y[0, 0, 3:]).tolist(),
        "peak_force": np.max(
            np.linalg.norm(wrench[:, :, :3], axis=-1), axis=0
        ).tolist(),
        "peak_torque": np.max(
            np.linalg.norm(wrench[:, :, 3:], axis=-1), axis=0
        ).tolist(),
        "energy": {
            "kinetic_final": float(kinetic[-1]),
            "elastic_final": float(elastic[-1]),
            "gravity_change": float(gravity[-1] - gravity[0]),
            "total_change": float(change),
            "work_of_forces": work,
            "dissipated": dissipated,
            "residual": float(residual),
            "relative_residual": float(abs(residual) / max(abs(work), 1e-300)),
        },
        "pairs": np.asarray(scenario.model.pairs).tolist(),
    }


def format_summary(s: dict) -> str:
    e = s["energy"]
    dx, dy, dz = s["object_displacement"]
    lines = [
        f"elasticoop: {s['scenario']} (MobileModel, 3 bodies, 2 elastic grasps)",
        f"  simulated {s['simulated_time']:.2f} s in {s['wall_time']:.2f} s wall "
        "(compilation included)",
        f"  object displacement: dx = {dx:+.5f} m, dy = {dy:+.5f} m, dz = {dz:+.5f} m",
        "  object rotation (Euler angles): "
        + ", ".join(f"{a:+.2e}" for a in s["object_rotation"])
        + " rad",
        "  peak elastic force per grasp:",
    ]
    for (i, j), f, t in zip(s["pairs"], s["peak_force"], s["peak_torque"]):
        lines.append(
            f"    grasp {j} (connection {i}-{j}): |force| {f:8.3f} N, "
            f"|torque| {t:.4f} N m"
        )
    lines += [
        "  energy balance [J]:",
        f"    work of manipulator forces  {e['work_of_forces']:+.6f}",
        f"    dissipated in the grasps    {e['dissipated']:+.6f}",
        f"    change of T + Pi + m g z    {e['total_change']:+.6f}"
        f"  (kinetic {e['kinetic_final']:.6f}, elastic {e['elastic_final']:.6f},"
        f" gravity {e['gravity_change']:+.6f})",
        f"    residual (change - work + dissipated) {e['residual']:+.2e}"
        f"  (relative {e['relative_residual']:.1e})",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(
        prog="elasticoop",
        description=(
            "Simulate the built-in scenario (two manipulators lifting a beam "
            "through elastic grasps) and print a summary."
        ),
    )
    parser.add_argument(
        "command", nargs="?", default="demo", choices=["demo"], help="what to run"
    )
    parser.add_argument("--rtol", type=float, default=1e-8, help="relative tolerance")
    parser.add_argument("--atol", type=float, default=1e-10, help="absolute tolerance")
    args = parser.parse_args(argv)
    try:
        summary = run_default(rtol=args.rtol, atol=args.atol)
    except (ValueError, SimulationError) as err:
        print(f"elasticoop: error: {err}", file=sys.stderr)
        return 2
    print(format_summary(summary))
    return 0


__all__ = ["main", "run_default", "format_summary"]
