"""Cost of the dynamics against the number of manipulators.

    python benchmarks/scaling.py [--quick] [--json out.json]

MobileModel with one object and m grasps on a circle, connected either as a star
(pairs (0, i), m connections) or all-pairs (every two bodies, (m + 1) m / 2
connections). Two costs per configuration: the library's right-hand side per state
(jitted, vmapped over 64 states, many evaluations in one compiled loop), and one
Tsit5 step of the full simulation vector field in diffrax (fixed step, one
trajectory). The fitted exponent is the slope of log cost against
log(bodies + connections) over the larger sizes (m >= 4), where fixed overheads
no longer dominate: 1 means linear.
"""

import sys
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import best_time, looped_rhs  # noqa: E402
from scenarios import vector_field  # noqa: E402

import elasticoop as eo  # noqa: E402
from elasticoop._lagrange import accelerations  # noqa: E402

UP = (0.0, np.pi / 2, 0.0)
BATCH = 64


def grasp_model(m: int, topology: str):
    bodies = [eo.RigidBody(2.0, (0.02, 0.15, 0.16))] + [
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3))
    ] * m
    if topology == "star":
        pairs = [(0, i) for i in range(1, m + 1)]
    else:
        pairs = [(i, j) for i in range(m + 1) for j in range(i + 1, m + 1)]
    conns = [
        eo.Connection(i, j, stiffness=(800.0,) * 3 + (20.0,) * 3, damping=(1.0,) * 6)
        for i, j in pairs
    ]
    angle = np.linspace(0, 2 * np.pi, m, endpoint=False)
    y = np.zeros((m + 1, 6))
    y[:, 2] = 1.0
    y[:, 3:] = UP
    y[1:, 0], y[1:, 1] = 0.5 * np.cos(angle), 0.5 * np.sin(angle)
    return eo.MobileModel(bodies, conns).with_unloaded_state(jnp.asarray(y)), y


def _rhs_cost(model, y, evals):
    rng = np.random.default_rng(0)
    ys = jnp.asarray(y + 0.01 * rng.normal(size=(BATCH, *y.shape)))
    vs = jnp.asarray(rng.normal(size=(BATCH, *y.shape)))
    fs = jnp.zeros_like(ys)
    n_evals = max(2, evals // BATCH)
    fn = looped_rhs(lambda m, a, b, f: accelerations(m, a, b, f)[0], n_evals)
    return best_time(fn, model, ys, vs, fs, repeats=3) / (n_evals * BATCH)


def _step_cost(model, y, n_steps):
    term = diffrax.ODETerm(vector_field)

    @jax.jit
    def solve(model, y0):
        sol = diffrax.diffeqsolve(
            term,
            diffrax.Tsit5(),
            t0=0.0,
            t1=n_steps * 1e-5,
            dt0=1e-5,
            y0=(y0, jnp.zeros_like(y0)),
            args=(model, None),
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=diffrax.ConstantStepSize(),
            max_steps=n_steps + 1,
        )
        return sol.ys[0]

    return best_time(solve, model, jnp.asarray(y), repeats=3) / n_steps


def _exponent(rows, key):
    rows = [r for r in rows if r["m"] >= 4 and r[key] is not None]
    if len(rows) < 2:
        return None
    x = np.log([r["bodies_plus_connections"] for r in rows])
    return float(np.polyfit(x, np.log([r[key] for r in rows]), 1)[0])


def run(quick: bool = False) -> dict:
    sizes = {
        "star": (1, 4) if quick else (1, 2, 4, 8, 16, 32, 64),
        "all_pairs": (2,) if quick else (1, 2, 4, 8, 16),
    }
    evals = 5_000 if quick else 200_000
    n_steps = 50 if quick else 2_000
    out = {
        "problem": f"right-hand side: us per state, vmapped over {BATCH} states; "
        "step: us per fixed Tsit5 step of the simulate vector field, 1 trajectory",
    }
    for topology, ms in sizes.items():
        rows = []
        for m in ms:
            model, y = grasp_model(m, topology)
            rows.append(
                {
                    "m": m,
                    "connections": model.n_connections,
                    "bodies_plus_connections": m + 1 + model.n_connections,
                    "rhs_us_per_state": 1e6 * _rhs_cost(model, y, evals),
                    "step_us": (
                        1e6 * _step_cost(model, y, n_steps)
                        if not quick or m == 1
                        else None
                    ),
                }
            )
        out[topology] = {
            "rows": rows,
            "rhs_exponent": _exponent(rows, "rhs_us_per_state"),
            "step_exponent": _exponent(rows, "step_us"),
        }
    return out


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
