"""`filter_jit`, with XLA options that shorten compilation: first-call latency.

In a fresh process the first `simulate` and the first scenario load are mostly XLA
compiling (`benchmarks/latency.py`). `FAST_COMPILE` turns off XLA's CPU fusion
emitters, so that fused loops are emitted by its older elemental emitter. On the
default scenario (2-core x86_64 CPU) the simulation then compiles in about 1.9 s
instead of 2.7 s and its static equilibrium in 0.75 s instead of 1.7 s, and they
run in the same time: one forward run 22.3-22.5 ms with or without it, and
`benchmarks/rhs.py`, `benchmarks/loop.py` and `benchmarks/montecarlo.py` agree
within their noise. It is an option of the CPU compiler; other backends ignore it.

JAX accepts compiler options only on the outermost compiled program, so
`fast_compile_jit` passes them only where its function is called outside any JAX
transformation; inside a user's `jit`, `vmap` or `grad` the function is traced into
the user's program, which compiles with the user's options. A user's own programs
are never affected.
"""

import functools
from collections.abc import Callable
from typing import Any, TypeVar, cast

import equinox as eqx
import jax.extend.core

_Fn = TypeVar("_Fn", bound=Callable[..., Any])

FAST_COMPILE: dict[str, str | bool | int] = {"xla_cpu_use_fusion_emitters": False}


def outside_transformations() -> bool:
    """True when no JAX transformation (`jit`, `vmap`, `grad`, ...) is tracing the
    caller: a program compiled from here is the outermost one."""
    return type(jax.extend.core.find_top_trace(())).__name__ == "EvalTrace"


def fast_compile_jit(fn: _Fn) -> _Fn:
    """`eqx.filter_jit(fn)`, compiled with `FAST_COMPILE` when called outside any
    JAX transformation (and inlined into the caller's program otherwise, as
    `eqx.filter_jit` is)."""
    nested = eqx.filter_jit(fn)
    # `filter_jit` passes further keywords on to `jax.jit` (its typed overloads
    # do not list them).
    outermost = eqx.filter_jit(fn, compiler_options=FAST_COMPILE)  # type: ignore[call-overload]

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        if outside_transformations():
            return outermost(*args, **kwargs)
        return nested(*args, **kwargs)

    call.lower = outermost.lower  # type: ignore[attr-defined]  # as filter_jit's
    return cast(_Fn, call)
