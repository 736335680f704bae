"""The integration loop's cost beyond the right-hand side, in a batch.

    python benchmarks/loop.py [--quick] [--json out.json]

Problem: the Monte Carlo study of `benchmarks/montecarlo.py` (3-body MobileModel,
2 connections, 2 s, rtol 1e-8, atol 1e-10, Tsit5, 12 log-normal stiffness
scalars), B = `run_study`'s default batch width (`montecarlo.DEFAULT_BATCH_WIDTH`,
128) samples (8 at smoke size) on one XLA device. Timed side by side in one
process after compilation, the calls in turn within each of 7 rounds, each the best
of its rounds (with 3 rounds the ratio moved between 1.29 and 1.37 from run to run):

- `solve`: `simulate` of every sample, `jax.vmap`-ed and jitted (the whole
  `Trajectory` returned): `vmap` of diffrax's loop;
- `solve_batch_loop`: the same with `batch_loop=True`, one loop for the batch (what
  `run_study` runs on a device);
- `rhs`: the vector field that `simulate` hands to diffrax (accelerations, work and
  dissipation rates on the packed state), `vmap`-ed over the same per-sample models,
  evaluated 6 times per step for the slowest sample's step count (a `vmap`-ed loop
  runs until its last lane is done; Tsit5 evaluates 6 new stages per step), the
  evaluations chained inside one compiled loop.

`solve_batch_loop / rhs` (and `solve / rhs`) is the loop's overhead factor: solver
arithmetic, step-size control, stop conditions and saving, and what `vmap` adds to
them. To show where it comes
from, also timed: the Tsit5 step alone (diffrax, a vector field that costs almost
nothing, dx/dt = -1e-9 c x, constant steps, as many as the slowest sample's),
`vmap`-ed over B states of the packed size and on one `(B, size)` state.
"""

import sys
from pathlib import Path

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from _timing import interleaved_best_times  # noqa: E402
from montecarlo import three_body_study  # noqa: E402

import elasticoop as eo  # noqa: E402
from elasticoop import montecarlo as mc  # noqa: E402
from elasticoop._forces import check_force  # noqa: E402
from elasticoop._simulate import _pack, _vector_field  # noqa: E402

STAGES_PER_STEP = 6  # Tsit5: 7 stages, the first reused from the step before


def run(quick: bool = False) -> dict:
    batch = 8 if quick else mc.DEFAULT_BATCH_WIDTH
    study = three_body_study(batch)
    inputs = study.inputs
    model = inputs.model
    stiffness = jnp.asarray(mc.sample_parameters(study, np.arange(batch))["stiffness"])
    y0, ydot0 = jnp.asarray(inputs.y_init), jnp.asarray(inputs.ydot_init)
    ts = jnp.asarray(study.ts)
    forces = jnp.asarray(inputs.forces.F)
    ts = ts[:3] if quick else ts

    def with_stiffness(k):
        return eqx.tree_at(lambda m: m.stiffness, model, k)

    def solver(batch_loop):
        @jax.jit
        def solve(stiffness):
            def one(k):
                traj = eo.simulate(
                    with_stiffness(k),
                    y0,
                    ydot0,
                    ts,
                    forces=forces,
                    rtol=1e-8,
                    atol=1e-10,
                    throw=False,
                    batch_loop=batch_loop,
                )
                return traj, traj.n_steps

            return jax.vmap(one)(stiffness)

        return solve

    solve, solve_batch_loop = solver(False), solver(True)
    _, steps = solve(stiffness)
    steps = np.asarray(steps)
    n_evals = STAGES_PER_STEP * int(steps.max())
    force = check_force(forces, y0, ydot0, ts)
    x0 = _pack(y0, ydot0, jnp.zeros(()), jnp.zeros(()))
    side = jnp.ones(model.n_bodies)

    @jax.jit
    def rhs(stiffness):
        def one(k):
            args = (with_stiffness(k), force, side, None, ts[-1])

            def evaluate(_, x):
                return x + 1e-9 * _vector_field(ts[1], x, args)

            return jax.lax.fori_loop(0, n_evals, evaluate, x0)

        return jax.vmap(one)(stiffness)

    n_steps = int(steps.max())
    states = jnp.ones((batch, x0.shape[0]))
    rates = jnp.linspace(1.0, 2.0, batch)
    step_vmapped, step_unbatched = _bare_steps(n_steps)
    times = interleaved_best_times(
        {
            "solve": (solve, (stiffness,)),
            "solve_batch_loop": (solve_batch_loop, (stiffness,)),
            "rhs": (rhs, (stiffness,)),
            "step_vmapped": (step_vmapped, (states, rates)),
            "step_unbatched": (step_unbatched, (states, rates)),
        },
        rounds=1 if quick else 7,
    )
    return {
        "problem": f"3-body MobileModel (2 connections), {float(ts[-1]):g} s, rtol "
        f"1e-8, Tsit5, {batch} samples vmapped on one device",
        "steps_mean": float(steps.mean()),
        "steps_max": int(steps.max()),
        "solve_ms_per_sample": 1e3 * times["solve"] / batch,
        "rhs_ms_per_sample": 1e3 * times["rhs"] / batch,
        "solve_over_rhs": times["solve"] / times["rhs"],
        "batch_loop_ms_per_sample": 1e3 * times["solve_batch_loop"] / batch,
        "batch_loop_over_rhs": times["solve_batch_loop"] / times["rhs"],
        "tsit5_step_alone_vmapped_us": 1e6 * times["step_vmapped"] / n_steps,
        "tsit5_step_alone_unbatched_us": 1e6 * times["step_unbatched"] / n_steps,
        "target": "batch_loop_over_rhs <= 1.3",
    }


def _bare_steps(n_steps: int):
    """Jitted `f(states, rates)`: `n_steps` constant Tsit5 steps of
    dx/dt = -1e-9 c x over [0, 1], `vmap`-ed over the rows of `states`
    (each with its own rate `c`), and the same on the whole `(B, size)` array."""

    def solve(x0, rate):
        return diffrax.diffeqsolve(
            diffrax.ODETerm(lambda t, x, c: -1e-9 * c * x),
            diffrax.Tsit5(),
            0.0,
            1.0,
            1.0 / n_steps,
            x0,
            args=rate,
            saveat=diffrax.SaveAt(t1=True),
            stepsize_controller=diffrax.ConstantStepSize(),
            max_steps=n_steps + 1,
        ).ys

    vmapped = jax.jit(jax.vmap(solve))
    unbatched = jax.jit(lambda xs, rates: solve(xs, rates[:, None]))
    return vmapped, unbatched


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
