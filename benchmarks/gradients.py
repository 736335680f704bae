"""Cost of a trajectory-loss gradient relative to one forward simulation.

    python benchmarks/gradients.py [--quick] [--json out.json]

Loss: sum of squared deviations of Y at the output times from a target trajectory,
for `default_scenario()` (3 s, 301 outputs; 0.1 s and the default adjoint only at
smoke size), as a function of all stiffness and damping parameters
(2 connections x 12 = 24). Forward:
`simulate` + loss, jitted. Gradients: `jax.grad` with
`RecursiveCheckpointAdjoint` (the default, `adjoint=None`: checkpoints chosen by
diffrax from `max_steps`, 446 for 100 000; and `checkpoints=2048`, more than the
run's steps, so that no step is recomputed twice), `jax.grad` with `BacksolveAdjoint`
(if diffrax accepts it here), and `jax.jacfwd` with `ForwardMode` (24 tangents).
Times are of compiled calls, best of 7 rounds in which the forward run and
each gradient are timed in turn; gradients are
cross-checked against each other.

Decomposition (what bounds the reverse-mode ratio): the run's steps, the vector
field alone and with its vector-Jacobian product (evaluated inside one compiled
loop, as in `benchmarks/rhs.py`), and the floor of a discrete adjoint that replays
each step once: the forward run plus, per step, the Tsit5 step's 6 new stages each
evaluated again with its vector-Jacobian product.
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

import elasticoop as eo  # noqa: E402
from elasticoop import _simulate, default_scenario  # noqa: E402
from elasticoop._forces import check_force  # noqa: E402


def make_loss(scenario, adjoint):
    s = scenario
    target = eo.simulate(s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces).y
    target = target + 1e-3  # a target the parameters do not reach

    def loss(params):
        model = eqx.tree_at(lambda m: (m.stiffness, m.damping), s.model, params)
        traj = eo.simulate(
            model,
            s.y_init,
            s.ydot_init,
            s.ts,
            forces=s.forces,
            adjoint=adjoint,
            throw=False,
        )
        return jnp.sum((traj.y - target) ** 2)

    return loss


def per_evaluation(scenario, n_evals: int) -> dict:
    """Microseconds per evaluation of `simulate`'s vector field at the initial
    state, alone and with its vector-Jacobian product with respect to the state and
    the model, `n_evals` times inside one compiled loop."""
    s = scenario
    force = check_force(s.forces, s.y_init, s.ydot_init, s.ts)
    side = jnp.ones(s.model.n_bodies)
    args = (s.model, force, side, None, s.ts[-1])
    x0 = _simulate._pack(s.y_init, s.ydot_init, jnp.zeros(()), jnp.zeros(()))
    t = s.ts[0]

    @jax.jit
    def alone(x0, args):
        def body(_, x):
            return x + 1e-9 * _simulate._vector_field(t, x, args)

        return jax.lax.fori_loop(0, n_evals, body, x0)

    @jax.jit
    def with_vjp(x0, args):
        def body(_, x):
            out, pullback = jax.vjp(
                lambda x, a: _simulate._vector_field(t, x, a), x, args
            )
            x_bar, args_bar = pullback(out)
            return x + 1e-9 * x_bar + 1e-12 * jnp.sum(args_bar[0].stiffness)

        return jax.lax.fori_loop(0, n_evals, body, x0)

    times = interleaved_best_times(
        {"alone": (alone, (x0, args)), "with_vjp": (with_vjp, (x0, args))}, 5
    )
    return {k: 1e6 * v / n_evals for k, v in times.items()}


def run(quick: bool = False) -> dict:
    s = default_scenario()
    if quick:
        s = eqx.tree_at(lambda sc: sc.ts, s, s.ts[:11])
    params = (s.model.stiffness, s.model.damping)
    rounds = 1 if quick else 7
    forward = jax.jit(make_loss(s, diffrax.RecursiveCheckpointAdjoint()))
    variants = {
        "reverse_RecursiveCheckpointAdjoint": (jax.grad, None),
        "reverse_RecursiveCheckpointAdjoint_2048": (
            jax.grad,
            diffrax.RecursiveCheckpointAdjoint(checkpoints=2048),
        ),
        "reverse_BacksolveAdjoint": (jax.grad, diffrax.BacksolveAdjoint()),
        "forward_ForwardMode_jacfwd": (jax.jacfwd, diffrax.ForwardMode()),
    }
    if quick:
        variants = {k: variants[k] for k in ("reverse_RecursiveCheckpointAdjoint",)}
    rows, grads, calls = [], {}, {"forward": (forward, (params,))}
    for name, (transform, adjoint) in variants.items():
        fn = jax.jit(transform(make_loss(s, adjoint)))
        start = time.perf_counter()
        try:
            g = jax.block_until_ready(fn(params))
        except Exception as err:  # an adjoint diffrax does not support here
            rows.append({"method": name, "error": f"{type(err).__name__}: {err}"[:200]})
            continue
        calls[name] = (fn, (params,))
        grads[name] = np.concatenate([np.ravel(x) for x in g])
        rows.append({"method": name, "first_call_s": time.perf_counter() - start})
    times = interleaved_best_times(calls, rounds)
    t_forward = times["forward"]
    for row in rows:
        if row["method"] in times:
            t = times[row["method"]]
            row.update(wall_ms=1e3 * t, over_forward=t / t_forward)
    base = grads.get("reverse_RecursiveCheckpointAdjoint")
    for row in rows:
        g = grads.get(row["method"])
        if g is not None and base is not None:
            row["max_rel_diff_vs_checkpoint"] = float(
                np.max(np.abs(g - base)) / np.max(np.abs(base))
            )
    steps = int(
        eo.simulate(s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces).n_steps
    )
    evals = per_evaluation(s, 200 if quick else 20_000)
    floor = t_forward + steps * 6 * 1e-6 * evals["with_vjp"]
    decomposition = {
        "steps": steps,
        "forward_us_per_step": 1e6 * t_forward / steps,
        "vector_field_us": evals["alone"],
        "vector_field_with_vjp_us": evals["with_vjp"],
        "vjp_over_vector_field": evals["with_vjp"] / evals["alone"],
        "replay_once_floor_ms": 1e3 * floor,
        "replay_once_floor_over_forward": floor / t_forward,
    }
    return {
        "decomposition": decomposition,
        "problem": f"default scenario, {float(s.ts[-1]):.1f} s, {len(s.ts)} outputs, "
        "24 parameters (stiffness, damping), Tsit5 rtol 1e-8",
        "forward_ms": 1e3 * t_forward,
        "rows": rows,
        "target": "reverse-mode gradient <= 4x forward",
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
