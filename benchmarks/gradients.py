"""Cost of a trajectory-loss gradient relative to one forward simulation.

    python benchmarks/gradients.py [--quick] [--json out.json]

Loss: sum of squared deviations of Y at the output times from a target trajectory,
for `default_scenario()` (3 s, 301 outputs; 0.1 s and the default adjoint and
`StepwiseAdjoint` only at smoke size), as a function of all stiffness and damping
parameters
(2 connections x 12 = 24). Forward:
`simulate` + loss, jitted. Gradients: `jax.grad` with
`RecursiveCheckpointAdjoint` (diffrax's default: checkpoints chosen by
diffrax from `max_steps`, 446 for 100 000; and `checkpoints=2048`, more than the
run's steps, so that no step is recomputed twice), `jax.grad` with the library's
`StepwiseAdjoint` (`simulate`'s default; also at smoke size; with
`max_steps=4096`, a few times the run's steps, all of which it keeps either way;
and with `kept_steps=512`, which keeps the start states of the first 512 steps
and of every 2nd or 4th after them, replaying the others), `jax.grad` with
`BacksolveAdjoint`
(if diffrax accepts it here), and `jax.jacfwd` with `ForwardMode` (24 tangents).
Scratch memory: XLA's temporary buffers of each compiled gradient (the difference
between the two checkpoint counts is what the checkpoints cost). Times are of
compiled calls, best of 7 rounds in which the forward run, each gradient and the
decomposition's loops are timed in turn; gradients are cross-checked against each
other. Batch: the forward run and the default gradient `vmap`-ped over 8 parameter
sets, and `StepwiseAdjoint`'s gradient `vmap`-ped (its forward half in the batch
loop), time per sample, best of 3 rounds (not at smoke size).

Decomposition (what bounds the reverse-mode ratio): the run's steps; the vector
field alone and with its vector-Jacobian product, evaluated inside one compiled
loop at the run's own output times and states, and the product in a loop on
state-sized arrays only (`per_evaluation`); the floor the cheaper of the two
products sets for any adjoint that takes, for each accepted step, the products of
its 6 evaluated stages (the forward run plus 6 products per accepted step: a
product evaluates its stage too, so replaying the step within it costs nothing
more); and,
measured, the backward pass of the plainest such adjoint (`stepwise_backward`),
whose time per step beyond its 6 products is the cost of the step's own
arithmetic and of the loop.

The adjoints' own cost (what bounds the ratio whatever the product costs): the
products replaced by stand-ins (`stand_in_product`, values wrong, timed only) that
cost one evaluation of the vector field (the least any product can cost) or
nothing, in diffrax's adjoint (a bare `diffrax.diffeqsolve` of simulate's vector
field with its controller, outputs and `max_steps`, `checkpoints=2048`; against
its own forward run) and in the stepwise adjoint. From these, the most the
backward half of a product may cost for the stepwise adjoint to stay within 4x
the forward run, and what autodiff's costs there. (At smoke size only the stand-in
that evaluates the field.)
"""

import dataclasses
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
from elasticoop._integrate.error_norm import rms_norm  # noqa: E402


def parameters(model):
    """The 24 parameters differentiated: `(stiffness, damping)`."""
    return (model.stiffness, model.damping)


def with_parameters(model, params):
    return eqx.tree_at(lambda m: (m.stiffness, m.damping), model, params)


def max_rel_diff(g, base) -> float:
    return float(np.max(np.abs(g - base)) / np.max(np.abs(base)))


# The settings of this benchmark's runs: Tsit5 at rtol 1e-8 (the decomposition
# below counts its 6 stages). `benchmarks/defaults.py` measures `simulate`'s
# default settings.
OPTIONS = eo.SimulationOptions("tsit5", 1e-8, 1e-10)


def target_trajectory(scenario):
    """What the losses measure deviations from: the scenario's positions, all
    shifted by 1 mm (a target the parameters do not reach)."""
    s = scenario
    traj = eo.simulate(
        s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces, options=OPTIONS
    )
    return traj.y + 1e-3


def make_loss(scenario, adjoint, max_steps: int = 100_000):
    s = scenario
    target = target_trajectory(s)

    def loss(params):
        traj = eo.simulate(
            with_parameters(s.model, params),
            s.y_init,
            s.ydot_init,
            s.ts,
            forces=s.forces,
            adjoint=adjoint,
            options=dataclasses.replace(OPTIONS, max_steps=max_steps),
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
        model = with_parameters(s.model, params)
        return _simulate._vector_field(t, x, (model, force, side, None, s.ts[-1]))

    return field


def product_loop(
    field, t0, x0, x_bar0, n_evals: int, width: int | None = None, axis: int = 0
):
    """A compiled loop of `n_evals` vector-Jacobian products of `field(t, x,
    params)` in the state and the parameters (two arrays), with the cotangent
    `x_bar0`, at `(t0, x0)` nudged by the previous result (so that nothing is
    computed once outside the loop): a function of the parameters. With `width`,
    the products of `width` parameter sets (the parameters with an axis of that
    length, leading or `axis`) under `vmap`, as the adjoint takes them under
    `vmap`."""

    def product(params, carry):
        x_bar, acc = carry
        t, x = t0 + 1e-12 * acc, x0 + 1e-12 * x_bar
        _, pullback = jax.vjp(lambda x, p: field(t, x, p), x, params)
        x_bar, p_bar = pullback(x_bar0)
        return x_bar, acc + jnp.sum(p_bar[0]) + jnp.sum(p_bar[1])

    return evaluation_loop(product, x0, n_evals, width, axis)


def evaluation_loop(body, x0, n_evals: int, width: int | None = None, axis: int = 0):
    """`n_evals` calls of `body(params, (x_bar, acc)) -> (x_bar, acc)` in a
    compiled loop, from zeros: a function of the parameters. With `width`, `body`
    under `vmap` over `width` lanes (parameters and `x_bar` each with an axis of
    that length, leading, or the last with `axis=-1`; `acc` `(width,)`)."""
    if width is None:
        step, x_shape, acc_shape = body, x0.shape, ()
    else:
        step = jax.vmap(body, in_axes=(axis, (axis, 0)), out_axes=(axis, 0))
        x_shape = (width, *x0.shape) if axis == 0 else (*x0.shape, width)
        acc_shape = (width,)

    @jax.jit
    def run(params):
        start = (jnp.zeros(x_shape), jnp.zeros(acc_shape))
        return jax.lax.fori_loop(0, n_evals, lambda k, c: step(params, c), start)

    return run


def per_evaluation(scenario, traj, n_evals: int) -> dict:
    """Compiled loops of `n_evals` evaluations of `simulate`'s vector field, alone
    (`alone`) and with its vector-Jacobian product with respect to the state and
    the 24 parameters (`with_vjp`), as `{name: (fn, args)}`.

    Evaluation k is at output k (modulo their number) of the scenario's own run
    `traj`: its time and state, nudged by the previous result so that no evaluation
    repeats another, and the product's cotangent is the next output's state.

    `with_vjp_small_arrays`: the same products at one output's time and state,
    nudged by the previous results (so that nothing can be computed once outside
    the loop), with a constant cotangent: a loop whose body touches no array of
    more than a state. XLA's CPU runtime runs such a body's operations one after
    the other, and a body that reads the outputs' array as a graph, with hand-offs
    to its thread pool (docs/performance.md)."""
    field = field_of_parameters(scenario)
    times = traj.ts
    states = jax.vmap(_simulate._pack)(traj.y, traj.ydot, traj.work, traj.dissipated)
    n = times.shape[0]

    def at(k, previous):
        return times[k % n], states[k % n] + 1e-12 * previous

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
            x_bar, p_bar = pullback(states[(k + 1) % n])
            return x_bar, acc + jnp.sum(p_bar[0]) + jnp.sum(p_bar[1])

        return jax.lax.fori_loop(
            0, n_evals, body, (jnp.zeros_like(states[0]), jnp.zeros(()))
        )

    t_fixed, x_fixed, x_bar_fixed = times[n // 2], states[n // 2], states[n // 2 + 1]

    with_vjp_small_arrays = product_loop(field, t_fixed, x_fixed, x_bar_fixed, n_evals)
    args = (parameters(scenario.model),)
    return {
        "alone": (alone, args),
        "with_vjp": (with_vjp, args),
        "with_vjp_small_arrays": (with_vjp_small_arrays, args),
    }


def initial_state(scenario):
    """The scenario's initial state as `simulate` integrates it."""
    s = scenario
    return _simulate._pack(s.y_init, s.ydot_init, jnp.zeros(()), jnp.zeros(()))


def bare_solve(scenario, field, params, saveat, max_steps, **kwargs):
    """`diffrax.diffeqsolve` of `field` over the scenario's outputs' span with
    simulate's solver and step-size controller (no stop conditions)."""
    s = scenario
    return diffrax.diffeqsolve(
        diffrax.ODETerm(field),
        diffrax.Tsit5(),
        s.ts[0],
        s.ts[-1],
        None,
        initial_state(s),
        params,
        saveat=saveat,
        stepsize_controller=diffrax.PIDController(  # simulate's
            rtol=1e-8, atol=1e-10, norm=rms_norm
        ),
        max_steps=max_steps,
        **kwargs,
    )


def stepwise_backward(scenario, field=None):
    """The backward pass of the plainest discrete adjoint, as `(fn, args)` and the
    run's accepted steps. Given those steps (times and states, from
    `diffrax.diffeqsolve` with the same vector field and controller), one
    `jax.lax.while_loop` from the last step to the first applies the
    vector-Jacobian product of each Tsit5 step (diffrax's tableau, unrolled) to
    the state's cotangent and adds up the 24 parameters' cotangents. The product
    of a step replays it from its stored start: its 6 evaluated stages (the first
    recomputed, since the step before's last stage is not kept; the 7th is not
    needed, the step's result being the last stage's input), each under
    `jax.checkpoint`, so that it is evaluated again with its product, and the
    product is applied inside a `jax.lax.cond` (on a predicate that always holds),
    whose operations XLA's CPU runtime runs one after the other (its operands are
    single states; the loop's body, which reads the stored steps, it runs as a
    graph with hand-offs to its thread pool): measured on the 3 s lift, 33 us per
    step against 80 us with the product applied in line (as diffrax's adjoint does
    when it keeps every step) and 93 us without `jax.checkpoint` either. No
    step-size control, outputs or stop conditions: a replaying discrete adjoint
    with everything but the steps taken away. `field`: the vector field whose
    products are taken (default: `field_of_parameters`; `stand_in_product` for the
    loop's own cost)."""
    s = scenario
    if field is None:
        field = field_of_parameters(s)
    tableau = diffrax.Tsit5.tableau
    a = [tuple(float(v) for v in row) for row in tableau.a_lower]
    c = tuple(float(v) for v in tableau.c)
    stage = jax.checkpoint(field)

    def step(x0, params, t0, h):
        ks = [stage(t0, x0, params)]
        for i, row in enumerate(a):
            x = x0 + h * sum(coef * k for coef, k in zip(row, ks, strict=True))
            if i < len(a) - 1:
                ks.append(stage(t0 + c[i] * h, x, params))
        return x  # the last row of a is b: the last stage's input is the result

    x0 = initial_state(s)
    sol = bare_solve(
        s, field, parameters(s.model), diffrax.SaveAt(t0=True, steps=True), 4096
    )
    n = int(sol.stats["num_accepted_steps"])
    ts, xs = sol.ts, sol.ys

    @jax.jit
    def backward(params):
        zeros = jax.tree.map(jnp.zeros_like, params)

        def body(carry):
            k, x_bar, p_bar = carry
            t0, h = ts[k], ts[k + 1] - ts[k]
            _, pullback = jax.vjp(lambda x, p: step(x, p, t0, h), xs[k], params)
            x_bar, p_step = jax.lax.cond(
                k >= 0,  # always: a branch of its own for the product
                lambda pullback, x_bar: pullback(x_bar),
                lambda pullback, x_bar: (x_bar, zeros),
                pullback,
                x_bar,
            )
            return k - 1, x_bar, jax.tree.map(jnp.add, p_bar, p_step)

        return jax.lax.while_loop(
            lambda carry: carry[0] >= 0, body, (n - 1, jnp.ones_like(x0), zeros)
        )

    return (backward, (parameters(s.model),)), n


def stand_in_product(field, evaluate: bool = True):
    """`field` with a stand-in for its vector-Jacobian product, for timing only
    (its values are wrong). With `evaluate`, the cotangents of the state and the
    parameters come from one more evaluation of the field, at the state nudged by
    the cotangent: a product costs at least that (it takes the field's
    derivatives at that point), so an adjoint run with it gives the least time that
    adjoint can take with any product, however written. Without, they are the
    incoming cotangent scaled (no cost at all): what is left is the adjoint's own
    cost."""

    @jax.custom_vjp
    def stand_in(t, x, params):
        return field(t, x, params)

    def forward(t, x, params):
        return field(t, x, params), (t, x, params)

    def backward(residuals, x_bar):
        t, x, params = residuals
        if evaluate:
            value = field(t, x + 1e-12 * x_bar, params)
        else:
            value = -1e-3 * x_bar
        total = jnp.sum(value)
        return jnp.zeros_like(t), value, jax.tree.map(lambda p: total * p, params)

    stand_in.defvjp(forward, backward)
    return stand_in


def bare_solve_losses(scenario, field):
    """The trajectory loss of `make_loss` through a bare `diffrax.diffeqsolve` of
    `field` (simulate's vector field, or a `stand_in_product`) with simulate's
    solver, controller, outputs and `max_steps` but not its stop conditions,
    differentiated by diffrax's adjoint with `checkpoints=2048`: `(forward,
    gradient)`, both jitted functions of the parameters."""
    s = scenario
    target = target_trajectory(s)

    def loss(params):
        sol = bare_solve(
            s,
            field,
            params,
            diffrax.SaveAt(ts=s.ts),
            100_000,
            adjoint=diffrax.RecursiveCheckpointAdjoint(checkpoints=2048),
        )
        y = _simulate._unpack(sol.ys)[0]
        return jnp.sum((y - target) ** 2)

    return jax.jit(loss), jax.jit(jax.grad(loss))


def batched(scenario, width: int, rounds: int) -> dict:
    """Forward run and reverse-mode gradient (the default adjoint, stepwise, and
    `RecursiveCheckpointAdjoint`) `vmap`-ped over `width`
    parameter sets (the scenario's, then stiffness and damping scaled by 1.00 to
    1.05, fixed seed): time per sample and their ratio, best of `rounds` rounds.
    Also returns the first sample's gradient (the scenario's own parameters), to
    cross-check."""
    loss = make_loss(scenario, diffrax.RecursiveCheckpointAdjoint())
    scale = 1 + 0.05 * jax.random.uniform(jax.random.key(0), (width, 1, 1))
    scale = scale.at[0].set(1.0)
    sets = tuple(p[None] * scale for p in parameters(scenario.model))
    # (the forward run as `vmap(simulate)` runs it by default: the batch loop)
    forward = jax.jit(jax.vmap(make_loss(scenario, None)))
    gradient = jax.jit(jax.vmap(jax.grad(loss)))
    stepwise = jax.jit(jax.vmap(jax.grad(make_loss(scenario, eo.StepwiseAdjoint()))))
    times = interleaved_best_times(
        {
            "forward": (forward, (sets,)),
            "gradient": (gradient, (sets,)),
            "stepwise": (stepwise, (sets,)),
        },
        rounds,
    )
    first = gradient(sets)
    first_stepwise = stepwise(sets)
    return {
        "width": width,
        "rounds": rounds,
        "forward_ms_per_sample": 1e3 * times["forward"] / width,
        "gradient_ms_per_sample": 1e3 * times["gradient"] / width,
        "over_forward": times["gradient"] / times["forward"],
        "stepwise_gradient_ms_per_sample": 1e3 * times["stepwise"] / width,
        "stepwise_over_forward": times["stepwise"] / times["forward"],
        "stepwise_max_rel_diff": max(
            max_rel_diff(a, b) for a, b in zip(first_stepwise, first, strict=True)
        ),
        "first_sample_gradient": np.concatenate([np.ravel(g[0]) for g in first]),
    }


def run(quick: bool = False) -> dict:
    s = default_scenario()
    if quick:
        s = eqx.tree_at(lambda sc: sc.ts, s, s.ts[:11])
    params = parameters(s.model)
    rounds = 1 if quick else 7
    forward = jax.jit(make_loss(s, diffrax.RecursiveCheckpointAdjoint()))
    # name: (transform, adjoint, max_steps)
    variants = {
        "reverse_RecursiveCheckpointAdjoint": (
            jax.grad,
            diffrax.RecursiveCheckpointAdjoint(),
            100_000,
        ),
        "reverse_RecursiveCheckpointAdjoint_2048": (
            jax.grad,
            diffrax.RecursiveCheckpointAdjoint(checkpoints=2048),
            100_000,
        ),
        "reverse_StepwiseAdjoint": (jax.grad, eo.StepwiseAdjoint(), 100_000),
        # the run's 1261 steps kept at max_steps=4096 (what the default keeps)
        "reverse_StepwiseAdjoint_max_steps_4096": (
            jax.grad,
            eo.StepwiseAdjoint(),
            4096,
        ),
        # 512 steps kept, then every 2nd and 4th: the others replayed
        "reverse_StepwiseAdjoint_kept_512": (
            jax.grad,
            eo.StepwiseAdjoint(kept_steps=512),
            100_000,
        ),
        "reverse_BacksolveAdjoint": (jax.grad, diffrax.BacksolveAdjoint(), 100_000),
        "forward_ForwardMode_jacfwd": (jax.jacfwd, diffrax.ForwardMode(), 100_000),
    }
    if quick:
        variants = {
            k: variants[k]
            for k in ("reverse_RecursiveCheckpointAdjoint", "reverse_StepwiseAdjoint")
        }
    rows, grads, calls = [], {}, {"forward": (forward, (params,))}
    for name, (transform, adjoint, max_steps) in variants.items():
        fn = jax.jit(transform(make_loss(s, adjoint, max_steps)))
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
    # The decomposition's loops, timed in the same rounds as the forward run.
    traj = eo.simulate(
        s.model, s.y_init, s.ydot_init, s.ts, forces=s.forces, options=OPTIONS
    )
    n_evals = 200 if quick else 20_000
    calls.update(per_evaluation(s, traj, n_evals))
    calls["stepwise_backward"], accepted = stepwise_backward(s)
    field = field_of_parameters(s)
    # (at smoke size only the stand-in that evaluates the field: each gradient
    # compiles for seconds)
    stand_ins = {"stand_in": stand_in_product(field)}
    bare_forward, bare_gradient = bare_solve_losses(s, field)
    calls["bare_forward"] = (bare_forward, (params,))
    if not quick:
        stand_ins["free"] = stand_in_product(field, evaluate=False)
        calls["bare_gradient"] = (bare_gradient, (params,))
    for name, f in stand_ins.items():
        calls[f"stepwise_backward_{name}"], _ = stepwise_backward(s, f)
        calls[f"bare_gradient_{name}"] = (bare_solve_losses(s, f)[1], (params,))
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
            row["max_rel_diff_vs_checkpoint"] = max_rel_diff(g, base)
    batch = {}
    if not quick:
        batch = batched(s, 8, 3)
        batch["max_rel_diff_vs_checkpoint"] = max_rel_diff(
            batch.pop("first_sample_gradient"), base
        )
    steps = int(traj.n_steps)
    vf_us = 1e6 * times["alone"] / n_evals
    vjp_us = 1e6 * times["with_vjp"] / n_evals
    # the least a product was measured to cost (a loop on state-sized arrays)
    product_us = min(vjp_us, 1e6 * times["with_vjp_small_arrays"] / n_evals)
    products = accepted * 6 * 1e-6 * product_us
    backward = times["stepwise_backward"]
    stand_in_backward = times["stepwise_backward_stand_in"]
    bare = times["bare_forward"]
    decomposition = {
        "steps": steps,
        "accepted_steps": accepted,
        "forward_us_per_step": 1e6 * t_forward / steps,
        "vector_field_us": vf_us,
        "vector_field_with_vjp_us": vjp_us,
        "vector_field_with_vjp_small_arrays_us": 1e6
        * times["with_vjp_small_arrays"]
        / n_evals,
        "vjp_over_vector_field": vjp_us / vf_us,
        "stage_products_us_per_step": 6 * product_us,
        "products_floor_over_forward": (t_forward + products) / t_forward,
        "stepwise_backward_ms": 1e3 * backward,
        "stepwise_backward_us_per_step": 1e6 * backward / accepted,
        "forward_plus_stepwise_backward_over_forward": (t_forward + backward)
        / t_forward,
        # The adjoints' own cost: the products replaced by a stand-in that costs
        # one evaluation of the vector field, or nothing (`stand_in_product`).
        "bare_solve_forward_ms": 1e3 * bare,
        **{
            f"bare_solve_{name}_over_forward": times[f"bare_{name}"] / bare
            for name in ("gradient", "gradient_stand_in", "gradient_free")
            if f"bare_{name}" in times
        },
        **{
            f"stepwise_backward_{name}_us_per_step": 1e6
            * times[f"stepwise_backward_{name}"]
            / accepted
            for name in stand_ins
        },
        **{
            f"forward_plus_stepwise_backward_{name}_over_forward": (
                t_forward + times[f"stepwise_backward_{name}"]
            )
            / t_forward
            for name in stand_ins
        },
        # What the backward half of a product may cost, at most, for the stepwise
        # adjoint to stay within 4x the forward run (the stand-in's is one
        # evaluation of the vector field), and what autodiff's costs there.
        "stepwise_product_budget_for_4x_us": vf_us
        + 1e6 * (3 * t_forward - stand_in_backward) / (6 * accepted),
        "stepwise_autodiff_product_us": vf_us
        + 1e6 * (backward - stand_in_backward) / (6 * accepted),
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
