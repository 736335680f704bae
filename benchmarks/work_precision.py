"""Work-precision diagrams: error against wall time for diffrax solvers.

    python benchmarks/work_precision.py [--quick] [--json out.json]

Scenarios: `default_scenario()` (3 bodies, 2 grasps, 3 s lift) and its stiff
variant (grasps 10x lighter, connections 10x stiffer; the stiffness ratio is
reported). Each solver runs the library's vector field (`simulate`'s, without
events) under a PID step-size controller with rtol from the list and
atol = rtol / 100; the error is the largest deviation of Y (m or rad) over the
301 output times from a reference at rtol 1e-12 (Dopri8, atol 1e-14). Wall time
is the compiled run, best of a few rounds in which the solvers are timed in turn
(runs over 0.5 s once). A plot is written to
`benchmarks/work_precision.png` (full run only; the smoke size runs the default
scenario for 0.1 s, Tsit5 and Kvaerno5 at one tolerance).
"""

import sys
import time
from pathlib import Path

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import interleaved_best_times  # noqa: E402
from scenarios import scenarios, stiffness_ratio, vector_field  # noqa: E402

PLOT = Path(__file__).resolve().parent / "work_precision.png"
SOLVERS = {
    "Tsit5": diffrax.Tsit5,
    "Dopri5": diffrax.Dopri5,
    "Dopri8": diffrax.Dopri8,
    "Kvaerno3": diffrax.Kvaerno3,
    "Kvaerno5": diffrax.Kvaerno5,
}


def make_solve(scenario, solver, max_steps):
    """A jitted `solve(rtol, atol) -> (Y at ts, steps)`; tolerances are traced, so
    one compilation serves the whole sweep."""
    s = scenario
    term = diffrax.ODETerm(vector_field)

    @jax.jit
    def solve(rtol, atol):
        sol = diffrax.diffeqsolve(
            term,
            solver,
            t0=s.ts[0],
            t1=s.ts[-1],
            dt0=None,
            y0=(s.y_init, s.ydot_init),
            args=(s.model, s.forces),
            saveat=diffrax.SaveAt(ts=s.ts),
            stepsize_controller=diffrax.PIDController(rtol=rtol, atol=atol),
            max_steps=max_steps,
            throw=False,
        )
        ok = sol.result == diffrax.RESULTS.successful
        return jnp.where(ok, sol.ys[0], jnp.nan), sol.stats["num_steps"]

    return solve


def _sweep(scenario, rtols, repeats, solvers=tuple(SOLVERS)):
    """Error, steps and wall time of every solver at every rtol. At each rtol the
    solvers whose run takes under 0.5 s are timed in turn, `repeats` rounds (so a
    slow spell of a shared machine hits them alike); longer runs are timed once."""
    ref, _ = make_solve(scenario, diffrax.Dopri8(), 2_000_000)(1e-12, 1e-14)
    ref = np.asarray(ref)
    solves = {name: make_solve(scenario, SOLVERS[name](), 100_000) for name in solvers}
    rows = []
    for rtol in rtols:
        args = (jnp.asarray(rtol), jnp.asarray(rtol / 100))
        runs, once = {}, {}
        for name, solve in solves.items():
            runs[name] = jax.block_until_ready(solve(*args))  # compiles at first
            start = time.perf_counter()
            jax.block_until_ready(solve(*args))
            once[name] = time.perf_counter() - start
            steps = int(runs[name][1])
            print(f"  {name} rtol {rtol:.0e}: {steps} steps", file=sys.stderr)
        short = {n: (solves[n], args) for n in solves if once[n] < 0.5}
        wall = dict(once)
        for name, t in interleaved_best_times(short, repeats).items():
            wall[name] = min(t, once[name])
        for name, (y, steps) in runs.items():
            err = float(np.max(np.abs(np.asarray(y) - ref)))
            rows.append(
                {
                    "solver": name,
                    "rtol": rtol,
                    "steps": int(steps),
                    "error": err if np.isfinite(err) else None,
                    "wall_ms": 1e3 * wall[name],
                }
            )
    order = {name: i for i, name in enumerate(solvers)}
    return sorted(rows, key=lambda r: order[r["solver"]])  # stable: rtols in order


def plot(results, path=PLOT):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [k for k in ("default", "stiff") if k in results]
    fig, axes = plt.subplots(1, len(names), figsize=(6 * len(names), 4.5))
    for ax, key in zip(np.atleast_1d(axes), names):
        rows = results[key]["rows"]
        for solver in SOLVERS:
            pts = [
                (r["wall_ms"], r["error"], r["rtol"])
                for r in rows
                if r["solver"] == solver and r["error"] is not None
            ]
            if not pts:
                continue
            t, e, _ = zip(*pts)
            style = "--" if solver.startswith("Kvaerno") else "-"
            ax.loglog(t, e, style, marker="o", label=solver)
        ratio = results[key]["stiffness_ratio"]
        ax.set_title(f"{key} scenario (stiffness ratio {ratio:.1e})")
        ax.set_xlabel("wall time per simulation [ms]")
        ax.set_ylabel("max |Y - Y_ref| [m, rad]")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend()
    fig.suptitle(
        "Work-precision, rtol 1e-3, 1e-5, 1e-7, 1e-9 (atol = rtol/100), 3 s lift"
    )
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return str(path)


def run(quick: bool = False, make_plot: bool | None = None) -> dict:
    rtols = (1e-5,) if quick else (1e-3, 1e-5, 1e-7, 1e-9)
    solvers = ("Tsit5", "Kvaerno5") if quick else tuple(SOLVERS)
    out = {
        "problem": "3 s two-arm lift, 301 outputs; error = max |Y - Y_ref| over "
        "outputs (reference Dopri8 rtol 1e-12); atol = rtol/100; wall time of the "
        "compiled run, one trajectory",
    }
    n_output = 301
    for key, scenario in scenarios(n_output).items():
        if quick and key != "default":
            continue
        if quick:  # shorter horizon at smoke size
            scenario = eqx.tree_at(lambda s: s.ts, scenario, scenario.ts[:11])
        out[key] = {
            "stiffness_ratio": stiffness_ratio(scenario),
            "rows": _sweep(scenario, rtols, 1 if quick else 5, solvers),
        }
    if make_plot if make_plot is not None else not quick:
        out["plot"] = plot(out)
    return out


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
