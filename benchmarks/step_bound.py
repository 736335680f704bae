"""What the bound on the step size costs and what it buys.

    python benchmarks/step_bound.py [--quick] [--json out.json]

`simulate` takes no step longer than the solver's stability radius over a bound of
the fastest rate of the motion linearized at the start
(`elasticoop._integrate.stability`). Here, for each explicit solver at the
tolerances of `benchmarks/defaults.py`:

- `steps`: the solver steps of `default_scenario()` (3 bodies, 3 s: a lift from
  rest), what the bound costs where the accuracy alone would allow longer steps;
- `radius`, `rate_bound`, `step_bound`: the stability radius, the bound of the
  rates at the start and their quotient [s], with `exact_rate`, the largest
  $|\\lambda|$ of the linearized motion (NumPy's eigenvalues of its first-order
  form), which the bound must not be below;
- `at_rest`: the derivative of the beam's final x with respect to its initial x
  for a run of 0.3 s at rest in the static equilibrium of the guide's model (the
  holding forces applied, nothing moving), by `jax.grad` and by a central
  difference (steps of 1e-6), and their relative difference. Without the bound
  the error control lets the steps grow at rest until the grasps' modes are
  unstable, and the gradient is orders of magnitude off.

- `compile_s`: what the bound adds to a program's compilation where the model is
  traced (under `jit`, `vmap` or `grad` the bound is part of the run's program):
  `jax.jit` of the scenario's final pose as a function of the stiffness, Dopri8,
  with the bound and with `simulate`'s `_stable_step` replaced by no bound, each
  compiled `rounds` times from a fresh lowering (JAX's caches cleared), the best
  of them, under `FAST_COMPILE` (the library's outermost programs and the tests')
  and under XLA's defaults (a user's own `jit`).

Run on the commit before the bound (`git checkout a440e54 -- elasticoop`), the
`steps` and `at_rest` parts measure the code without it (the rest needs the bound).
At smoke size (`--quick`): the first 0.3 s of the scenario, Dopri8 only, one round.
"""

import sys
import time
from pathlib import Path

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import scipy.linalg

sys.path.insert(0, str(Path(__file__).resolve().parent))

import elasticoop as eo  # noqa: E402
from elasticoop import _simulate  # noqa: E402
from elasticoop._compile_options import FAST_COMPILE, XLA_DEFAULTS  # noqa: E402

SOLVERS = {
    "dopri8 (default)": eo.SimulationOptions(),
    "tsit5, rtol 1e-8": eo.SimulationOptions("tsit5", 1e-8, 1e-10),
    "dopri5, rtol 1e-8": eo.SimulationOptions("dopri5", 1e-8, 1e-10),
}


def exact_rate(model, y) -> float:
    n = y.size
    K = np.asarray(
        jax.hessian(lambda q: model.potential(q.reshape(y.shape)))(y.ravel())
    )
    D = np.asarray(
        jax.hessian(lambda v: model.dissipation(y, v.reshape(y.shape)))(np.zeros(n))
    )
    W = scipy.linalg.block_diag(*np.asarray(eo.mass_matrix(model, y)))
    A = np.block(
        [
            [np.zeros((n, n)), np.eye(n)],
            [-np.linalg.solve(W, K), -np.linalg.solve(W, D)],
        ]
    )
    return float(np.max(np.abs(np.linalg.eigvals(A))))


def beam_at_rest():
    """The guide's beam held in its grasps, at rest in the static equilibrium under
    the holding forces: `(model, y0, holding forces)`. Nothing moves, and the error
    control sees nothing."""
    beam, grasp = eo.RigidBody(2.0, (0.004, 0.17, 0.17)), eo.RigidBody(0.3, (1e-3,) * 3)
    up = (0.0, np.pi / 2, 0.0)
    rest = jnp.array([[0, 0, 1, *up], [-0.5, 0, 1, *up], [0.5, 0, 1, *up]])
    grasps = [
        eo.Connection(
            0, i, stiffness=(2e4,) * 3 + (40.0,) * 3, damping=(60.0,) * 3 + (0.4,) * 3
        )
        for i in (1, 2)
    ]
    model = eo.MobileModel([beam, grasp, grasp], grasps).with_unloaded_state(rest)
    held = np.zeros((3, 6), bool)
    held[1:] = True
    start = eo.static_equilibrium(model, rest, held)
    return model, start.y, start.reaction[1:]


def at_rest(options) -> dict:
    model, y0, holding = beam_at_rest()
    ts = jnp.linspace(0.0, 0.3, 7)

    def end_x(y):
        run = eo.simulate(
            model, y, jnp.zeros_like(y), ts, forces=holding, options=options
        )
        return run.y[-1, 0, 0]

    h = 1e-6
    central = float((end_x(y0.at[0, 0].add(h)) - end_x(y0.at[0, 0].add(-h))) / (2 * h))
    grad = float(jax.grad(end_x)(y0)[0, 0])
    return {"grad": grad, "central": central, "rel_diff": abs(grad / central - 1)}


def compile_seconds(s, ts, rounds: int) -> dict:
    """Best compilation time [s] of a run's program with a traced model, with and
    without the bound, under `FAST_COMPILE` and XLA's defaults."""
    jax.config.update("jax_enable_compilation_cache", False)

    def final_pose(stiffness):
        model = eqx.tree_at(lambda m: m.stiffness, s.model, stiffness)
        return eo.simulate(model, s.y_init, s.ydot_init, ts, forces=s.forces).y[-1]

    bounded = _simulate._stable_step

    def unbounded(model, y, solver):
        return jnp.asarray(jnp.inf, y.dtype)

    best: dict = {}
    for _ in range(rounds):
        for options_name, options in (
            ("fast_compile", FAST_COMPILE),
            ("xla_defaults", XLA_DEFAULTS),
        ):
            for bound_name, stable_step in (
                ("with_bound", bounded),
                ("without", unbounded),
            ):
                _simulate._stable_step = stable_step
                try:
                    jax.clear_caches()
                    lowered = jax.jit(final_pose).lower(s.model.stiffness)
                    start = time.perf_counter()
                    lowered.compile(compiler_options=options)
                    seconds = time.perf_counter() - start
                finally:
                    _simulate._stable_step = bounded
                key = f"{options_name}, {bound_name}"
                best[key] = min(best.get(key, np.inf), seconds)
    return best


def run(quick: bool = False) -> dict:
    s = eo.default_scenario()
    ts = s.ts[:31] if quick else s.ts
    solvers = dict(list(SOLVERS.items())[:1]) if quick else SOLVERS
    y = jnp.asarray(s.y_init)
    rows = []
    for name, options in solvers.items():
        traj = eo.simulate(s.model, s.y_init, s.ydot_init, ts, forces=s.forces,
                           options=options)  # fmt: skip
        row = {"solver": name, "steps": int(traj.n_steps)}
        try:  # (the bound's own functions: absent before it)
            from elasticoop._integrate.stability import stability_radius
            from elasticoop._lagrange import linear_rate_bound
        except ImportError:
            pass
        else:
            radius = stability_radius(options.diffrax_solver())
            rate = float(jax.jit(linear_rate_bound)(s.model, y))
            row |= {
                "radius": radius,
                "rate_bound": rate,
                "exact_rate": exact_rate(s.model, y),
                "step_bound": radius / rate,
            }
        row["at_rest"] = at_rest(options)
        rows.append(row)
    return {
        "problem": f"default_scenario(), {float(ts[-1]):g} s; the guide's beam at "
        "rest, 0.3 s",
        "rows": rows,
        "compile_s": compile_seconds(s, ts, 1 if quick else 3),
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
