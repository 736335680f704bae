"""Core figures of the simulator, measured in one run.

    python benchmarks/core.py [--json results.json]

Reports, each with its problem size:

- energy drift of the undamped, unforced 3-body MobileModel over 2 s (~20 periods of
  the slowest link mode) at rtol 1e-10,
- gradient check: jax.grad of a trajectory loss w.r.t. the 24 stiffness and damping
  parameters against central finite differences,
- right-hand-side cost for m = 1 .. 64 grasps (pairs (0, i)), jitted, vmapped over
  64 states, with the fitted exponent of cost vs. bodies + connections,
- wall time of the main job (`python -m elasticoop`) in a fresh process.
"""

import argparse
import json
import platform
import subprocess
import sys
import time

import equinox as eqx
import jax
import jax.flatten_util
import jax.numpy as jnp
import numpy as np

import elasticoop as eo
from elasticoop._lagrange import accelerations

UP = (0.0, np.pi / 2, 0.0)


def three_body(damping=True):
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    damp = (3.0, 2.5, 2.0, 0.05, 0.04, 0.06) if damping else (0.0,) * 6
    conns = [
        eo.Connection(0, i, stiffness=(800, 900, 1000, 20, 25, 30), damping=damp)
        for i in (1, 2)
    ]
    y = jnp.array([[0, 0, 1, *UP], [-0.5, 0, 1, *UP], [0.5, 0, 1, *UP]])
    return eo.MobileModel(bodies, conns).with_unloaded_state(y), y


def energy_drift():
    model, y = three_body(damping=False)
    y = y.at[1, :3].add(jnp.array([-0.02, 0.01, 0.015]))
    ydot = jnp.zeros_like(y).at[0].set(jnp.array([0.1, -0.2, 0.3, 0.5, -0.4, 0.3]))
    ts = jnp.linspace(0.0, 2.0, 401)
    traj = eo.simulate(model, y, ydot, ts, rtol=1e-10, atol=1e-12)
    energy = np.asarray(traj.total_energy())
    mech = float(traj.kinetic_energy()[0] + traj.elastic_energy()[0])
    return {
        "problem": "3 bodies, 2 connections, 2 s, rtol 1e-10, atol 1e-12",
        "max_relative_drift": float(np.max(np.abs(energy - energy[0])) / mech),
    }


def gradient_check():
    model, y = three_body()
    y = y.at[1, :3].add(jnp.array([-0.01, 0.005, 0.01]))
    ydot = jnp.zeros_like(y).at[0, :3].set(jnp.array([0.1, 0.0, 0.2]))
    ts = jnp.linspace(0.0, 0.2, 21)
    target = eo.simulate(model, y, ydot, ts).y * 1.01

    @jax.jit
    def loss(params):
        m = eqx.tree_at(lambda m: (m.stiffness, m.damping), model, params)
        traj = eo.simulate(m, y, ydot, ts, rtol=1e-12, atol=1e-14)
        return jnp.sum((traj.y - target) ** 2)

    params = (model.stiffness, model.damping)
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    g, _ = jax.flatten_util.ravel_pytree(jax.grad(loss)(params))
    fd = np.zeros(flat.shape[0])
    for k in range(flat.shape[0]):
        e = jnp.zeros_like(flat).at[k].set(1e-4 * abs(float(flat[k])))
        fd[k] = (loss(unravel(flat + e)) - loss(unravel(flat - e))) / (2 * e[k])
    err = np.abs(np.asarray(g) - fd)
    return {
        "problem": "24 parameters, 0.2 s, rtol 1e-12, FD relative step 1e-4",
        "max_error_relative_to_max_gradient": float(np.max(err) / np.max(np.abs(fd))),
        "median_entrywise_relative_error": float(
            np.median((err / np.abs(fd))[np.abs(fd) > 1e-6 * np.max(np.abs(fd))])
        ),
    }


def rhs_scaling(batch=64, repeats=20):
    rows = []
    for m in (1, 2, 4, 8, 16, 32, 64):
        bodies = [eo.RigidBody(2.0, (0.02, 0.15, 0.16))] + [
            eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3))
        ] * m
        conns = [
            eo.Connection(
                0, i, stiffness=(800.0,) * 3 + (20.0,) * 3, damping=(1.0,) * 6
            )
            for i in range(1, m + 1)
        ]
        angle = np.linspace(0, 2 * np.pi, m, endpoint=False)
        pos = np.stack([np.cos(angle), np.sin(angle), np.ones(m)], axis=1) * 0.5
        y = np.zeros((m + 1, 6))
        y[:, 3:] = UP
        y[1:, :3] = pos
        model = eo.MobileModel(bodies, conns).with_unloaded_state(jnp.array(y))
        rng = np.random.default_rng(0)
        ys = jnp.array(y + 0.01 * rng.normal(size=(batch, m + 1, 6)))
        vs = jnp.array(rng.normal(size=(batch, m + 1, 6)))

        @jax.jit
        def rhs(ys, vs, model=model):
            zero = jnp.zeros_like(ys[0])
            return jax.vmap(lambda a, b: accelerations(model, a, b, zero)[0])(ys, vs)

        rhs(ys, vs).block_until_ready()
        best = np.inf
        for _ in range(repeats):
            t = time.perf_counter()
            rhs(ys, vs).block_until_ready()
            best = min(best, time.perf_counter() - t)
        rows.append(
            {
                "m": m,
                "bodies_plus_connections": 2 * m + 1,
                "us_per_state": 1e6 * best / batch,
            }
        )
    x = np.log([r["bodies_plus_connections"] for r in rows[2:]])
    yv = np.log([r["us_per_state"] for r in rows[2:]])
    slope = float(np.polyfit(x, yv, 1)[0])
    return {
        "problem": f"pairs (0, i), vmapped over {batch} states, best of {repeats}",
        "rows": rows,
        "fitted_exponent_m_ge_4": slope,
    }


def main_job_wall_time():
    t = time.perf_counter()
    subprocess.run(
        [sys.executable, "-m", "elasticoop"], check=True, capture_output=True
    )
    return {
        "problem": "python -m elasticoop, fresh process, 3 s simulated",
        "wall_s": time.perf_counter() - t,
    }


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", help="write the results to this file")
    args = parser.parse_args()
    results = {
        "machine": f"{platform.machine()} {platform.processor()} "
        f"{jax.devices()[0].platform} x{len(jax.devices())}",
        "jax": jax.__version__,
        "energy_drift": energy_drift(),
        "gradient_check": gradient_check(),
        "rhs_scaling": rhs_scaling(),
        "main_job": main_job_wall_time(),
    }
    print(json.dumps(results, indent=2))
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=2)


if __name__ == "__main__":
    main()
