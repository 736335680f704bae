"""Shared timing helpers: best-of-N wall time, RHS evaluations inside one compiled
loop, and a description of the machine."""

import os
import platform
import time

import jax
import numpy as np


def best_time(fn, *args, repeats: int = 5) -> float:
    """Best wall time [s] of `fn(*args)` over `repeats` calls, after one warm-up
    call (compilation excluded), waiting for the result."""
    jax.block_until_ready(fn(*args))
    best = np.inf
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(fn(*args))
        best = min(best, time.perf_counter() - start)
    return float(best)


def interleaved_best_times(calls: dict, rounds: int, repeats: int = 1) -> dict:
    """Best wall time [s] of each call over `rounds` rounds of `repeats` calls,
    the calls (`{name: (fn, args)}`) timed in turn within a round (so slow spells
    of a shared machine hit them alike), after one warm-up call each."""
    for fn, args in calls.values():
        jax.block_until_ready(fn(*args))
    best = dict.fromkeys(calls, np.inf)
    for _ in range(rounds):
        for name, (fn, args) in calls.items():
            for _ in range(repeats):
                start = time.perf_counter()
                jax.block_until_ready(fn(*args))
                best[name] = min(best[name], time.perf_counter() - start)
    return {name: float(t) for name, t in best.items()}


def looped_rhs(rhs, n_evals: int):
    """A jitted `f(args, ys, vs, forces)` that evaluates `rhs(args, y, v, force)`,
    vmapped over the leading axis, `n_evals` times inside one `fori_loop`, each
    evaluation feeding the next (as inside an ODE solver). This measures the
    right-hand side itself rather than Python dispatch; `args` is traced (a model
    passed like `simulate` passes it) or `None`."""
    batched = jax.vmap(rhs, in_axes=(None, 0, 0, 0))

    @jax.jit
    def run(args, ys, vs, forces):
        def step(_, state):
            y, v = state
            a = batched(args, y, v, forces)
            return y + 1e-9 * v, v + 1e-9 * a

        return jax.lax.fori_loop(0, n_evals, step, (ys, vs))

    return run


def machine() -> str:
    """CPU/accelerator, core count and library versions, for the results."""
    device = jax.devices()[0]
    return (
        f"{platform.machine()} {platform.processor() or ''} {os.cpu_count()} cores, "
        f"{device.platform} ({device.device_kind}), jax {jax.__version__}"
    ).replace("  ", " ")
