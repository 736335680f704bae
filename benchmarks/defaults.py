"""What a user gets without options: `simulate`'s defaults under `vmap` and `grad`.

    python benchmarks/defaults.py [--quick] [--json out.json]
    taskset -c 0 python benchmarks/defaults.py     # on one core

Three measurements, each ratio from calls timed in turn in one process (best of
`rounds` rounds), so that slow spells of a shared machine hit both sides alike:

- `vmap`: the user code `jax.jit(jax.vmap(run))` with `run(stiffness)` =
  `simulate(model with stiffness, ...).y` at `simulate`'s defaults, against a loop
  of SciPy `solve_ivp` (DOP853, rtol 1e-8, atol 1e-10) over the NumPy right-hand
  side of `benchmarks/reference.py`, timed on a few samples (in the same rounds as
  the library's calls) and extrapolated to the batch. Problem: the 3-body
  `MobileModel` of `benchmarks/montecarlo.py` (object + 2 grasps, 2 connections), 2
  s, 21 output times, constant lift, a batch of 1024 grasp stiffnesses (12 scalars,
  log-normal, 20 % scatter). Side by side: the same user code with the settings that
  were the defaults before (`Tsit5` at rtol 1e-8, `vmap` of diffrax's loop).
  Accuracy: max |Y - Y_ref| over the outputs of the nominal model, Y_ref by Dopri8
  at rtol 1e-13, of the defaults and of SciPy's run (the target is the defaults'
  error no larger than SciPy's).
- `grad`: `jax.grad` of a trajectory loss (the sum of squared deviations of Y at
  the 301 output times of `default_scenario()`, 3 s, from a target 1 mm away) with
  respect to the 24 stiffness and damping parameters, at `simulate`'s defaults,
  against one forward run (the loss, jitted); and its two halves timed alone: the
  forward run that records the accepted steps (`record`) and the backward pass
  (`backward`), with the run's accepted steps.
  What bounds it: `product_us` and `field_us`, the vector-Jacobian product of
  `simulate`'s vector field in the state and the 24 parameters and the field
  alone, each `n_evals` times in a compiled loop whose body touches single states
  only (as the adjoint applies it), at a state of the run
  (`product_over_field`, their ratio; `field_share`, the share of the forward
  run that evaluates the field at `field_us` each); and
  `backward_us_per_evaluation`, the backward pass's time over the forward run's
  evaluations of the field (steps times the evaluations per step: the stages less
  one, the last stage of a step being the first of the next, 13 for Dopri8): a
  product, its replayed evaluation and their share of the loops around them.
  And the backward pass in place, taken apart (`backward_parts`): traced again
  with the stages' products replaced by a stand-in that costs nothing
  (`backward_no_products_over_forward`), and with the replay of the stages too
  (`backward_no_products_no_replay_over_forward`: the loops and the outputs'
  shares alone); the differences are what the products and the replay cost
  where they run.
- `vmap_grad`: the same gradient `vmap`-ped over 8 parameter sets against the
  `vmap`-ped forward run (both at the defaults: the forward run in the batch loop),
  and its two halves alone (`vmap_record`, `vmap_backward`).
  What bounds it: `vmap_field_us` and `vmap_product_us`, the field and its
  product under `vmap` over the 8 sets in compiled loops, and `vmap_field_share`,
  the share of the `vmap`-ped forward run that evaluates the field (the nominal
  set's steps times the evaluations per step, at `vmap_field_us` each);
  `last_axis_field_us` and `last_axis_product_us`, the same loops with the sets
  as the last axis of the parameters and states instead of the first; the same
  parts of the backward pass as above (`vmap_backward_no_products_over_vmap_forward`,
  `vmap_backward_no_products_no_replay_over_vmap_forward`); and
  `per_set_us`, the field and its product per set in loops under `vmap` over 1,
  2, 4, 8 and 16 sets (the batch's time over its sets).

At smoke size (`--quick`): 8 samples, 0.2 s, 11 outputs, one round.
"""

import os
import sys
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import reference  # noqa: E402
from _timing import interleaved_best_times  # noqa: E402

import elasticoop as eo  # noqa: E402

UP = (0.0, np.pi / 2, 0.0)
# the settings that were `simulate`'s defaults before
BEFORE = eo.SimulationOptions("tsit5", 1e-8, 1e-10)


def three_body():
    """`benchmarks/montecarlo.py`'s model, initial state and lift."""
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    damp = (3.0, 2.5, 2.0, 0.05, 0.04, 0.06)
    conns = [
        eo.Connection(0, i, stiffness=(800, 900, 1000, 20, 25, 30), damping=damp)
        for i in (1, 2)
    ]
    y0 = np.array([[0, 0, 1, *UP], [-0.5, 0, 1, *UP], [0.5, 0, 1, *UP]])
    model = eo.MobileModel(bodies, conns).with_unloaded_state(y0)
    lift = np.zeros((2, 6))
    lift[:, 2] = 12.0
    return model, jnp.asarray(y0), jnp.zeros(y0.shape), lift


def vmap_throughput(batch: int, t_end: float, n_out: int, rounds: int, n_scipy: int):
    model, y0, ydot0, lift = three_body()
    ts = jnp.linspace(0.0, t_end, n_out)
    rng = np.random.default_rng(0)
    scale = np.exp(0.2 * rng.normal(size=(batch, *model.stiffness.shape)))
    stiffness = jnp.asarray(np.asarray(model.stiffness) * scale)

    def run(stiffness, **settings):
        m = eqx.tree_at(lambda m: m.stiffness, model, stiffness)
        return eo.simulate(m, y0, ydot0, ts, forces=lift, **settings).y

    calls = {
        "default": (jax.jit(jax.vmap(run)), (stiffness,)),
        "before": (
            jax.jit(jax.vmap(lambda k: run(k, options=BEFORE, batch_loop=False))),
            (stiffness,),
        ),
    }

    def scipy_loop():
        """SciPy, one sample after the other, on the first `n_scipy` samples."""
        for k in stiffness[:n_scipy]:
            m = eqx.tree_at(lambda m: m.stiffness, model, k)
            reference.solve_ivp_mobile(
                m, np.asarray(y0), np.asarray(ydot0), np.asarray(ts), force=lift,
                rtol=1e-8, atol=1e-10, method="DOP853",
            )  # fmt: skip

    compile_s = {}
    for name, (fn, args) in calls.items():
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        compile_s[name] = time.perf_counter() - start
    # SciPy timed in the same rounds as the two (a loaded machine slows all alike)
    calls["scipy"] = (scipy_loop, ())
    times = interleaved_best_times(calls, rounds)
    scipy_s = times["scipy"] * batch / n_scipy

    # accuracy on the nominal model
    ref = eo.simulate(
        model, y0, ydot0, ts, forces=lift,
        options=eo.SimulationOptions("dopri8", 1e-13, 1e-15),
    ).y  # fmt: skip
    scipy_y = reference.solve_ivp_mobile(
        model, np.asarray(y0), np.asarray(ydot0), np.asarray(ts), force=lift,
        rtol=1e-8, atol=1e-10, method="DOP853",
    )  # fmt: skip

    def error(y):
        return float(np.max(np.abs(np.asarray(y) - np.asarray(ref))))

    errors = {
        "default": error(eo.simulate(model, y0, ydot0, ts, forces=lift).y),
        "before": error(
            eo.simulate(model, y0, ydot0, ts, forces=lift, options=BEFORE).y
        ),
        "scipy_dop853_rtol_1e-08": error(scipy_y),
    }
    return {
        "problem": f"3-body MobileModel, {t_end:g} s, {n_out} outputs, batch {batch}",
        "cores": len(os.sched_getaffinity(0)),
        "scipy_samples_timed": n_scipy,
        "scipy_s_extrapolated": scipy_s,
        "default_s": times["default"],
        "before_s": times["before"],
        "default_over_scipy_speedup": scipy_s / times["default"],
        "before_over_scipy_speedup": scipy_s / times["before"],
        "compile_s": compile_s,
        "max_error_nominal": errors,
        "default_error_at_most_scipy": errors["default"]
        <= errors["scipy_dop853_rtol_1e-08"],
    }


def product_loops(s, traj, n_evals: int, sets, lanes=None, widths=()) -> dict:
    """`{name: (fn, args)}`: `n_evals` evaluations of `simulate`'s vector field
    (`field`) and of its vector-Jacobian product in the state and the stiffness and
    damping (`product`), in compiled loops on single states: each at the run's
    middle output, nudged by the previous result (so that nothing is computed once
    outside the loop); `vmap_field` and `vmap_product` the same under `vmap` over
    the parameter `sets` (a leading axis each), and `last_axis_field` and
    `last_axis_product` with the sets as the last axis of the parameters and the
    states instead. For each of `widths`, `lanes{w}_field` and `lanes{w}_product`
    the same under `vmap` over the first `w` of the parameter sets `lanes`."""
    from gradients import evaluation_loop, field_of_parameters, parameters, product_loop

    from elasticoop import _simulate

    field = field_of_parameters(s)
    states = jax.vmap(_simulate._pack)(traj.y, traj.ydot, traj.work, traj.dissipated)
    middle = states.shape[0] // 2
    t0, x0, x_bar0 = traj.ts[middle], states[middle], states[middle + 1]

    def evaluate(params, carry):
        x_bar, acc = carry
        return field(t0 + 1e-12 * acc, x0 + 1e-12 * x_bar, params), acc

    def loops(prefix, sets, width, axis=0):
        return {
            f"{prefix}field": (
                evaluation_loop(evaluate, x0, n_evals, width, axis),
                (sets,),
            ),
            f"{prefix}product": (
                product_loop(field, t0, x0, x_bar0, n_evals, width, axis),
                (sets,),
            ),
        }

    width = sets[0].shape[0]
    last = tuple(jnp.moveaxis(p, 0, -1) for p in sets)
    calls = loops("", parameters(s.model), None) | loops("vmap_", sets, width)
    calls |= loops("last_axis_", last, width, -1)
    for w in widths:
        calls |= loops(f"lanes{w}_", tuple(p[:w] for p in lanes), w)
    return calls


def parameter_sets(params, width: int):
    """`width` sets of the parameters, each scaled by a factor within 5 %."""
    scale = 1 + 0.05 * jax.random.uniform(jax.random.key(0), (width, 1, 1))
    return tuple(p[None] * scale for p in params)


def _free_product(field, h, t, x, k_bar, d, p_bar):
    """A stand-in for `adjoint.stage_product` that costs nothing: the cotangents
    scaled (values wrong, timed only; they still depend on the stage, so that
    nothing is left out of the compiled backward pass)."""
    total = jnp.sum(k_bar)
    return 1e-3 * k_bar + 1e-9 * x, jax.tree.map(lambda p: p + 1e-12 * total, p_bar)


def _free_replay(tableau, field, t0, t1, y0, f0, k_buffer, **_):
    """A stand-in for the replay's Runge-Kutta step (`adjoint.explicit_step`) that
    evaluates nothing: every stage's input is the step's start (values wrong)."""
    from elasticoop._integrate.rk_step import BatchStep

    inputs = jnp.broadcast_to(y0[None], (tableau.num_stages, *y0.shape))
    return BatchStep(y0, None, k_buffer, None, inputs)


def _unchanged(fn):
    return fn


def backward_parts(loss, params, sets) -> dict:
    """`{name: (fn, args)}`: the backward passes of the gradient (`backward_...`)
    and of its `vmap` (`vmap_backward_...`) with the stages' vector-Jacobian
    products replaced by a stand-in that costs nothing (`no_products`), and with
    the replay of the stages' inputs replaced too (`no_products_no_replay`): what
    the backward pass costs beyond its products, and beyond both. Each is traced
    and compiled with the stand-ins in place of the adjoint's own functions, after
    JAX's caches are cleared (so that no earlier trace is reused), and they are
    cleared again afterwards."""
    from unittest import mock

    from elasticoop._integrate import adjoint

    variants = {
        "no_products": {"stage_product": _free_product},
        "no_products_no_replay": {
            "stage_product": _free_product,
            "explicit_step": _free_replay,
        },
    }
    calls = {}
    for name, stand_ins in variants.items():
        jax.clear_caches()
        with mock.patch.multiple(adjoint, **stand_ins):
            for prefix, args, transform in (
                ("", params, _unchanged),
                ("vmap_", sets, jax.vmap),
            ):
                _, pullback = jax.jit(transform(lambda p: jax.vjp(loss, p)))(args)
                backward = jax.jit(transform(lambda pull: pull(jnp.ones(()))))
                backward = backward.lower(pullback).compile()
                calls[f"{prefix}backward_{name}"] = (backward, (pullback,))
    jax.clear_caches()
    return calls


def gradients(
    t_index: int | None,
    width: int,
    rounds: int,
    n_evals: int = 20_000,
    widths: tuple[int, ...] = (1, 2, 4, 8, 16),
):
    s = eo.default_scenario()
    ts = s.ts if t_index is None else s.ts[:t_index]
    params = (s.model.stiffness, s.model.damping)

    def trajectory(params):
        model = eqx.tree_at(lambda m: (m.stiffness, m.damping), s.model, params)
        return eo.simulate(model, s.y_init, s.ydot_init, ts, forces=s.forces).y

    target = trajectory(params) + 1e-3
    model = eqx.tree_at(lambda m: (m.stiffness, m.damping), s.model, params)
    traj = eo.simulate(model, s.y_init, s.ydot_init, ts, forces=s.forces)
    steps = traj.n_steps

    def loss(params):
        return jnp.sum((trajectory(params) - target) ** 2)

    sets = parameter_sets(params, width)
    # the gradient's two halves: the forward run that records the steps (the
    # pullback is returned, so that the record is computed), and the backward pass
    record = jax.jit(lambda p: jax.vjp(loss, p))
    _, pullback = record(params)
    vmap_record = jax.jit(jax.vmap(lambda p: jax.vjp(loss, p)))
    _, vmap_pullback = vmap_record(sets)
    calls = {
        "forward": (jax.jit(loss), (params,)),
        "grad": (jax.jit(jax.grad(loss)), (params,)),
        "record": (record, (params,)),
        "backward": (jax.jit(lambda pull: pull(jnp.ones(()))), (pullback,)),
        "vmap_forward": (jax.jit(jax.vmap(loss)), (sets,)),
        "vmap_grad": (jax.jit(jax.vmap(jax.grad(loss))), (sets,)),
        "vmap_record": (vmap_record, (sets,)),
        "vmap_backward": (
            jax.jit(jax.vmap(lambda pull: pull(jnp.ones(())))),
            (vmap_pullback,),
        ),
    }
    # the first call of each (tracing, compiling and one run)
    compile_s = {}
    for name in ("forward", "grad"):
        fn, args = calls[name]
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        compile_s[name] = time.perf_counter() - start
    # (and the field and its product per set, by the number of sets `vmap` takes)
    lanes = parameter_sets(params, max(widths))
    calls.update(product_loops(s, traj, n_evals, sets, lanes, widths))
    calls.update(backward_parts(loss, params, sets))
    times = interleaved_best_times(calls, rounds)
    stages = eo.SimulationOptions().diffrax_solver().tableau.num_stages
    # the forward run's evaluations of the field: the stages less one a step, the
    # last stage of a step being the first of the next
    evaluations = int(steps) * (stages - 1)
    return {
        "problem": f"default_scenario(), {float(ts[-1]):g} s, {len(ts)} outputs, "
        f"24 parameters; vmap over {width} parameter sets",
        "forward_ms": 1e3 * times["forward"],
        "grad_ms": 1e3 * times["grad"],
        "grad_over_forward": times["grad"] / times["forward"],
        "compile_s": compile_s,
        "steps": int(steps),
        "record_over_forward": times["record"] / times["forward"],
        "backward_over_forward": times["backward"] / times["forward"],
        "field_us": 1e6 * times["field"] / n_evals,
        "product_us": 1e6 * times["product"] / n_evals,
        "product_over_field": times["product"] / times["field"],
        "backward_us_per_evaluation": 1e6 * times["backward"] / evaluations,
        "field_share": times["field"] / n_evals * evaluations / times["forward"],
        "vmap_forward_ms": 1e3 * times["vmap_forward"],
        "vmap_grad_ms": 1e3 * times["vmap_grad"],
        "vmap_grad_over_vmap_forward": times["vmap_grad"] / times["vmap_forward"],
        "vmap_record_over_vmap_forward": times["vmap_record"] / times["vmap_forward"],
        "vmap_backward_over_vmap_forward": times["vmap_backward"]
        / times["vmap_forward"],
        "vmap_field_us": 1e6 * times["vmap_field"] / n_evals,
        "vmap_product_us": 1e6 * times["vmap_product"] / n_evals,
        "vmap_product_over_field": times["vmap_product"] / times["vmap_field"],
        # the backward passes with the products, and the replay, left out
        # (`backward_parts`), in forward runs
        **{
            f"{prefix}backward_{part}_over_{prefix}forward": times[
                f"{prefix}backward_{part}"
            ]
            / times[f"{prefix}forward"]
            for prefix in ("", "vmap_")
            for part in ("no_products", "no_products_no_replay")
        },
        # what a set costs in a batch of w (the time of the batch over w)
        "per_set_us": {
            str(w): {
                part: 1e6 * times[f"lanes{w}_{part}"] / n_evals / w
                for part in ("field", "product")
            }
            for w in widths
        },
        # the sets as the last axis of the arrays instead of the first
        "last_axis_field_us": 1e6 * times["last_axis_field"] / n_evals,
        "last_axis_product_us": 1e6 * times["last_axis_product"] / n_evals,
        # (the nominal set's steps: each set takes about as many)
        "vmap_field_share": times["vmap_field"]
        / n_evals
        * evaluations
        / times["vmap_forward"],
    }


def run(quick: bool = False) -> dict:
    if quick:
        vmap = vmap_throughput(8, 0.2, 11, 1, 2)
        grad = gradients(11, 2, 1, n_evals=100, widths=(1, 2))
    else:
        vmap = vmap_throughput(1024, 2.0, 21, 3, 16)
        grad = gradients(None, 8, 5)
    return {
        "vmap": vmap,
        "grad": grad,
        "targets": "vmap >= 150x SciPy at no larger error; grad <= 4x forward; "
        "vmap of grad <= 4.5x vmap of forward",
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
