"""XLA compiler options: compilation time against run time of the library's programs.

    python benchmarks/compile_options.py [--quick] [--json out.json]

Each program is compiled under each set of options below, the compilations and the
runs timed in turn in every round, the best of `rounds` each. Each compilation is
of a fresh lowering after JAX's caches are cleared, with JAX's persistent cache off,
so that no compiled program is reused. Every set gives all the options it is about,
so that `XLA_FLAGS` changes none of them:

- `xla_defaults`: XLA's own values of `FAST_COMPILE`'s options;
- `fusion_emitters_off`: `xla_cpu_use_fusion_emitters=False`, what
  `FAST_COMPILE` held before;
- `fast_compile`: `elasticoop._compile_options.FAST_COMPILE` as it is now (the
  options the library compiles its outermost programs with, and the tests all of
  theirs);
- `optimization_level_0`: the fusion emitters off and XLA's backend optimisation
  level 0 (shown for what it costs at run time).

Programs (`default_scenario()`: 3 bodies, 2 grasps, 3 s, 301 outputs, `simulate`'s
defaults): `simulate` (`forward`), `jax.grad` of a trajectory loss with respect
to the 24 stiffness and damping parameters (`grad`, the stepwise adjoint), the
trajectory's Jacobian with respect to them in forward mode (`jacfwd`, with
`diffrax.ForwardMode()`, as identification's Levenberg-Marquardt takes it), and
`simulate` under `jax.vmap` over 64 stiffness samples (`vmap_forward`, the batch
loop). At smoke size (`--quick`): 0.2 s, 8 samples, one round.
"""

import sys
import time
from pathlib import Path

import diffrax
import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from gradients import with_parameters  # noqa: E402

import elasticoop as eo  # noqa: E402
from elasticoop._compile_options import FAST_COMPILE, XLA_DEFAULTS  # noqa: E402

OPTIONS = {
    "xla_defaults": XLA_DEFAULTS,
    "fusion_emitters_off": {**XLA_DEFAULTS, "xla_cpu_use_fusion_emitters": False},
    "fast_compile": dict(FAST_COMPILE),
    "optimization_level_0": {
        "xla_cpu_use_fusion_emitters": False,
        "xla_backend_optimization_level": 0,
    },
}


def programs(t_end: float, width: int) -> dict:
    """`{name: (function, args)}` of the programs compared."""
    s = eo.default_scenario()
    ts = s.ts[s.ts <= t_end + 1e-12]
    params = (s.model.stiffness, s.model.damping)

    def trajectory(params, adjoint=None):
        return eo.simulate(
            with_parameters(s.model, params),
            s.y_init,
            s.ydot_init,
            ts,
            forces=s.forces,
            adjoint=adjoint,
        ).y

    target = trajectory(params) + 1e-3

    def loss(params):
        return jnp.sum((trajectory(params) - target) ** 2)

    scale = 1 + 0.2 * jax.random.uniform(jax.random.key(0), (width, 1, 1))
    return {
        "forward": (loss, (params,)),
        "grad": (jax.grad(loss), (params,)),
        "jacfwd": (
            jax.jacfwd(lambda p: trajectory(p, diffrax.ForwardMode())),
            (params,),
        ),
        "vmap_forward": (
            jax.vmap(lambda k: trajectory((k, params[1]))),
            (params[0] * scale,),
        ),
    }


def run(quick: bool = False) -> dict:
    assert set(XLA_DEFAULTS) == set(FAST_COMPILE)
    jax.config.update("jax_enable_compilation_cache", False)
    t_end, width, rounds, repeats = (0.2, 8, 1, 2) if quick else (3.0, 64, 3, 5)
    compile_s = {}
    run_s = {}
    results = {}
    compared = programs(t_end, width)
    for name, (fn, args) in compared.items():
        jitted = jax.jit(fn)
        for _ in range(rounds):
            for label, options in OPTIONS.items():
                # (a fresh lowering, with JAX's caches cleared: nothing reused)
                jax.clear_caches()
                lowered = jitted.lower(*args)
                start = time.perf_counter()
                compiled = lowered.compile(compiler_options=options)
                seconds = time.perf_counter() - start
                key = (name, label)
                compile_s[key] = min(compile_s.get(key, np.inf), seconds)
                out = jax.block_until_ready(compiled(*args))
                results[key] = out
                for _ in range(repeats):
                    start = time.perf_counter()
                    jax.block_until_ready(compiled(*args))
                    seconds = time.perf_counter() - start
                    run_s[key] = min(run_s.get(key, np.inf), seconds)
    rows = []
    for name in compared:
        reference = jax.tree.leaves(results[name, "xla_defaults"])
        for label in OPTIONS:
            leaves = jax.tree.leaves(results[name, label])
            gap = max(
                float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
                / max(float(np.max(np.abs(np.asarray(b)))), 1e-300)
                for a, b in zip(leaves, reference, strict=True)
            )
            rows.append(
                {
                    "program": name,
                    "options": label,
                    "compile_s": compile_s[name, label],
                    "run_ms": 1e3 * run_s[name, label],
                    "compile_vs_defaults": compile_s[name, label]
                    / compile_s[name, "xla_defaults"],
                    "run_vs_defaults": run_s[name, label] / run_s[name, "xla_defaults"],
                    "max_rel_diff_vs_defaults": gap,
                }
            )
    return {
        "problem": f"default_scenario(), {t_end:g} s; vmap over {width} samples",
        "fast_compile": repr(FAST_COMPILE),
        "rows": rows,
    }


if __name__ == "__main__":
    from _cli import main

    main(run, __doc__)
