"""The main job (`python -m elasticoop`, `elasticoop demo`): simulate the built-in
scenario and print a readable summary; and the `elasticoop` console script."""

import dataclasses
import time

from ._export import scenario_summary
from ._scenario import default_scenario


def run_default(rtol: float = 1e-8, atol: float = 1e-10) -> dict:
    """Simulate `default_scenario()` and return its summary as a dict."""
    scenario = dataclasses.replace(default_scenario(), rtol=rtol, atol=atol)
    start = time.perf_counter()
    traj = scenario.simulate()
    traj.y.block_until_ready()
    return scenario_summary(scenario, traj, time.perf_counter() - start)


def format_summary(s: dict) -> str:
    """The summary of a run (see `elasticoop._export.summarize`) as text."""
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
        "  peak elastic force per grasp:",
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
        f"  (kinetic {e['kinetic_final']:.6f}, elastic {e['elastic_final']:.6f},"
        f" gravity {e['gravity_change']:+.6f})",
        f"    residual (change - work + dissipated) {e['residual']:+.2e}"
        f"  (relative {e['relative_residual']:.1e})",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    """The `elasticoop` command line (see `elasticoop --help`)."""
    from ._cli import main as cli_main

    return cli_main(argv)


__all__ = ["main", "run_default", "format_summary"]
