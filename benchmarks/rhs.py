"""The library's autodiff right-hand side against the fast hand-written one.

    python benchmarks/rhs.py [--quick] [--json out.json]

3-body MobileModel (object + 2 grasps, 2 connections, ZXZ), states near the
unloaded one with random rates and forces. Each right-hand side is jitted, vmapped
over a batch of 1, 64 or 4096 states and evaluated many times inside one compiled
loop (so Python dispatch is not timed); the model is passed to the library as a
traced argument, as `simulate` does, while the hand-written reference has its
parameters compiled in. Ratios are of times measured side by side in one process,
best of several interleaved rounds. Also shown: a straightforward autodiff version
(jacfwd mass matrix, `jnp.linalg.solve` per body, gradients through gathers, i.e.
scatter-adds) and the plain NumPy right-hand side (one state per call).
"""

import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import interleaved_best_times, looped_rhs  # noqa: E402
from reference import fast_jax_rhs, numpy_params, numpy_rhs  # noqa: E402

import elasticoop as eo  # noqa: E402
from elasticoop._lagrange import accelerations  # noqa: E402

UP = (0.0, np.pi / 2, 0.0)


def three_body_model():
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    conns = [
        eo.Connection(
            0,
            i,
            stiffness=(800.0, 900.0, 1000.0, 20.0, 25.0, 30.0),
            damping=(3.0, 2.5, 2.0, 0.05, 0.04, 0.06),
        )
        for i in (1, 2)
    ]
    y = np.array([[0, 0, 1, *UP], [-0.5, 0, 1, *UP], [0.5, 0, 1, *UP]])
    return eo.MobileModel(bodies, conns).with_unloaded_state(y), y


def straightforward_autodiff(model, y, ydot, applied):
    """The direct transcription: per-body 6x6 `jacfwd` of the momentum, a generic
    `jnp.linalg.solve`, and dPi/dY, dR/dYdot by `jax.grad` through the gathers
    `y[pairs]` (whose transposes are scatter-adds)."""

    def body_terms(body, q, v):
        def energy(q, v):
            return eo.kinetic_energy(body, model.rotation, q, v)

        momentum = jax.grad(energy, argnums=1)
        W = jax.jacfwd(momentum, argnums=1)(q, v)
        _, rate = jax.jvp(lambda x: momentum(x, v), (q,), (v,))
        return W, rate - jax.grad(energy, argnums=0)(q, v)

    W, c = jax.vmap(body_terms)(model.bodies, y, ydot)
    elastic = jax.grad(model.potential)(y)
    damping = jax.grad(model.dissipation, argnums=1)(y, ydot)
    rhs = model.gravity_forces() + applied - c - damping - elastic
    return jax.vmap(jnp.linalg.solve)(W, rhs)


def _states(y0, batch, seed=0):
    rng = np.random.default_rng(seed)
    ys = jnp.asarray(y0 + 0.02 * rng.normal(size=(batch, *y0.shape)))
    vs = jnp.asarray(rng.normal(size=(batch, *y0.shape)))
    fs = jnp.asarray(rng.normal(size=(batch, *y0.shape)))
    return ys, vs, fs


def run(quick: bool = False) -> dict:
    model, y0 = three_body_model()
    params = numpy_params(model)
    variants = {
        "library": (lambda m, y, v, f: accelerations(m, y, v, f)[0], model),
        "fast_hand_written": (lambda _, y, v, f: fast_jax_rhs(params, y, v, f), None),
        "straightforward_autodiff": (straightforward_autodiff, model),
    }
    batches = (1, 64) if quick else (1, 64, 4096)
    evals = 5_000 if quick else 400_000  # state evaluations per timed call
    rounds = 1 if quick else 3
    rows = []
    for batch in batches:
        ys, vs, fs = _states(y0, batch)
        n_evals = max(2, evals // batch)
        calls = {
            name: (looped_rhs(fn, n_evals), (args, ys, vs, fs))
            for name, (fn, args) in variants.items()
        }
        times = interleaved_best_times(calls, rounds, repeats=3)
        best = {name: t / (n_evals * batch) for name, t in times.items()}
        row = {"batch": batch}
        row.update({f"{name}_us": 1e6 * t for name, t in best.items()})
        row["library_over_fast"] = best["library"] / best["fast_hand_written"]
        row["straightforward_over_fast"] = (
            best["straightforward_autodiff"] / best["fast_hand_written"]
        )
        rows.append(row)
    y, v, f = (np.asarray(a[0]) for a in _states(y0, 1))
    start, calls = time.perf_counter(), 0
    while calls == 0 or time.perf_counter() - start < (0.05 if quick else 1.0):
        numpy_rhs(params, y, v, f)
        calls += 1
    numpy_us = 1e6 * (time.perf_counter() - start) / calls
    return {
        "problem": "3 bodies, 2 connections (ZXZ); us per state evaluation, "
        f"{evals} evaluations per timed call, best of {rounds} interleaved rounds",
        "rows": rows,
        "numpy_rhs_us_per_call": numpy_us,
        "target": "library_over_fast <= 1.25",
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
