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
Scratch memory: XLA's temporary buffers of each compiled gradient (what the
checkpoints cost). Times are of compiled calls, best of 7 rounds in which the
forward run and each gradient are timed in turn; gradients are cross-checked
against each other. Batch: the forward run and the default
gradient `vmap`-ped over 8 parameter sets, time per sample (not at smoke size).

Decomposition (what bounds the reverse-mode ratio): the run's steps; the vector
field alone and with its vector-Jacobian product, evaluated inside one compiled
loop at the run's own output times and states; two floors from these per-call
costs, over the accepted steps: an adjoint that keeps each step's stage values
(the forward run plus 6 products per step) and one that replays each step once
(6 more evaluations per step); and, measured, the backward pass of the plainest
replaying discrete adjoint (`stepwise_backward`).
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


def field_of_parameters(scenario):
    """`simulate`'s vector field `(t, x, (stiffness, damping)) -> dx/dt` for the
    scenario's model and forces, free along the outputs' whole span."""
    s = scenario
    force = check_force(s.forces, s.y_init, s.ydot_init, s.ts)
    side = jnp.ones(s.model.n_bodies)

    def field(t, x, params):
        model = eqx.tree_at(lambda m: (m.stiffness, m.damping), s.model, params)
        return _simulate._vector_field(t, x, (model, force, side, None, s.ts[-1]))

    return field


def per_evaluation(scenario, n_evals: int) -> dict:
    """Microseconds per evaluation of `simulate`'s vector field, alone and with its
    vector-Jacobian product with respect to the state and the 24 parameters, each
    `n_evals` times inside one compiled loop.

    Evaluation k is at output k (modulo their number) of the scenario's own run:
    its time and state, nudged by the previous result so that no evaluation repeats
    another. (At one fixed time, as an earlier version measured, the product read
    3.4-3.6 us against 4.8-5.2 us here, the vector field 1.1 against 1.4 us: what
    depends on the time alone, such as the force's reference motion, is then
    computed once, outside the loop, which the solve never can.)"""
    s = scenario
    field = field_of_parameters(s)
    traj = eo.simulate(s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces)
    times = traj.ts
    states = jax.vmap(_simulate._pack)(traj.y, traj.ydot, traj.work, traj.dissipated)
    params = (s.model.stiffness, s.model.damping)

    def at(k, previous):
        k = k % times.shape[0]
        return times[k], states[k] + 1e-12 * previous

    @jax.jit
    def alone(params):
        def body(k, out):
            t, x = at(k, out)
            return field(t, x, params)

        return jax.lax.fori_loop(0, n_evals, body, jnp.zeros_like(states[0]))

    @jax.jit
    def with_vjp(params):
        def body(k, carry):
            x_bar, acc = carry
            t, x = at(k, x_bar)
            _, pullback = jax.vjp(lambda x, p: field(t, x, p), x, params)
            x_bar, p_bar = pullback(jnp.ones_like(x))
            return x_bar, acc + jnp.sum(p_bar[0]) + jnp.sum(p_bar[1])

        return jax.lax.fori_loop(
            0, n_evals, body, (jnp.zeros_like(states[0]), jnp.zeros(()))
        )

    per_call = interleaved_best_times(
        {"alone": (alone, (params,)), "with_vjp": (with_vjp, (params,))}, 5
    )
    return {k: 1e6 * v / n_evals for k, v in per_call.items()}


def stepwise_backward(scenario, rounds: int) -> dict:
    """The backward pass of the plainest discrete adjoint, measured: given the run's
    accepted steps (times and states, from `diffrax.diffeqsolve` with the same
    vector field and controller), one `jax.lax.while_loop` from the last step to
    the first applies the vector-Jacobian product of each Tsit5 step (diffrax's
    tableau, unrolled) to the state's cotangent and adds up the 24 parameters'
    cotangents. Each step is replayed once from its stored start (its 7 stages,
    the first recomputed), and each stage, under `jax.checkpoint`, is evaluated
    again with its product (54 against 67 us per step for the product of the
    whole step). No step-size control, outputs or stop conditions: what is left of
    a replaying discrete adjoint once everything but the steps is taken away."""
    s = scenario
    field = field_of_parameters(s)
    params = (s.model.stiffness, s.model.damping)
    tableau = diffrax.Tsit5.tableau
    a = [tuple(float(v) for v in row) for row in tableau.a_lower]
    c = tuple(float(v) for v in tableau.c)

    stage = jax.checkpoint(field)  # each stage replayed with its product

    def step(x0, params, t0, h):
        ks = [stage(t0, x0, params)]
        for i, row in enumerate(a):
            x = x0 + h * sum(coef * k for coef, k in zip(row, ks, strict=True))
            if i < len(a) - 1:
                ks.append(stage(t0 + c[i] * h, x, params))
        return x  # the last stage's input is the step's result (FSAL)

    x0 = _simulate._pack(s.y_init, s.ydot_init, jnp.zeros(()), jnp.zeros(()))
    max_steps = 4096
    sol = diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        diffrax.Tsit5(),
        s.ts[0],
        s.ts[-1],
        None,
        x0,
        params,
        saveat=diffrax.SaveAt(t0=True, steps=True),
        stepsize_controller=diffrax.PIDController(rtol=1e-8, atol=1e-10),
        max_steps=max_steps,
    )
    n = int(sol.stats["num_accepted_steps"])
    ts, xs = sol.ts, sol.ys

    @jax.jit
    def backward(params):
        def body(carry):
            k, x_bar, p_bar = carry
            t0, h = ts[k], ts[k + 1] - ts[k]
            _, pullback = jax.vjp(lambda x, p: step(x, p, t0, h), xs[k], params)
            x_bar, p_step = pullback(x_bar)
            return k - 1, x_bar, jax.tree.map(jnp.add, p_bar, p_step)

        zeros = jax.tree.map(jnp.zeros_like, params)
        return jax.lax.while_loop(
            lambda carry: carry[0] >= 0, body, (n - 1, jnp.ones_like(x0), zeros)
        )

    seconds = interleaved_best_times({"backward": (backward, (params,))}, rounds)
    return {
        "accepted_steps": n,
        "seconds": seconds["backward"],
        "us_per_step": 1e6 * seconds["backward"] / n,
    }


def batched(scenario, width: int, rounds: int) -> dict:
    """Forward run and default reverse-mode gradient `vmap`-ped over `width`
    parameter sets (the scenario's, then stiffness and damping scaled by 1.00 to
    1.05, fixed seed): time per sample and their ratio. Also returns the first
    sample's gradient (the scenario's own parameters), to cross-check."""
    loss = make_loss(scenario, None)
    params = (scenario.model.stiffness, scenario.model.damping)
    scale = 1 + 0.05 * jax.random.uniform(jax.random.key(0), (width, 1, 1))
    scale = scale.at[0].set(1.0)
    sets = tuple(p[None] * scale for p in params)
    forward = jax.jit(jax.vmap(loss))
    gradient = jax.jit(jax.vmap(jax.grad(loss)))
    first = jax.block_until_ready(gradient(sets))
    times = interleaved_best_times(
        {"forward": (forward, (sets,)), "gradient": (gradient, (sets,))}, rounds
    )
    return {
        "width": width,
        "forward_ms_per_sample": 1e3 * times["forward"] / width,
        "gradient_ms_per_sample": 1e3 * times["gradient"] / width,
        "over_forward": times["gradient"] / times["forward"],
        "first_sample_gradient": np.concatenate([np.ravel(g[0]) for g in first]),
    }


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
        first = time.perf_counter() - start
        memory = fn.lower(params).compile().memory_analysis()
        rows.append(
            {
                "method": name,
                "first_call_s": first,
                "scratch_mb": None
                if memory is None
                else memory.temp_size_in_bytes / 1e6,
            }
        )
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
    batch = {}
    if not quick:
        batch = batched(s, 8, 3)
        g = batch.pop("first_sample_gradient")
        batch["max_rel_diff_vs_checkpoint"] = float(
            np.max(np.abs(g - base)) / np.max(np.abs(base))
        )
    steps = int(
        eo.simulate(s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces).n_steps
    )
    evals = per_evaluation(s, 200 if quick else 20_000)
    backward = stepwise_backward(s, rounds)
    vjps = backward["accepted_steps"] * 6 * 1e-6 * evals["with_vjp"]
    replay = backward["accepted_steps"] * 6 * 1e-6 * evals["alone"]
    decomposition = {
        "steps": steps,
        "accepted_steps": backward["accepted_steps"],
        "forward_us_per_step": 1e6 * t_forward / steps,
        "vector_field_us": evals["alone"],
        "vector_field_with_vjp_us": evals["with_vjp"],
        "vjp_over_vector_field": evals["with_vjp"] / evals["alone"],
        "no_replay_floor_over_forward": (t_forward + vjps) / t_forward,
        "replay_once_floor_over_forward": (t_forward + replay + vjps) / t_forward,
        "stepwise_backward_ms": 1e3 * backward["seconds"],
        "stepwise_backward_us_per_step": backward["us_per_step"],
        "forward_plus_stepwise_backward_over_forward": (t_forward + backward["seconds"])
        / t_forward,
    }
    return {
        "batch_of_8": batch,
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
