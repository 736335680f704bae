"""`filter_jit`, with XLA options that shorten compilation: first-call latency.

In a fresh process the first `simulate` and the first scenario load are mostly XLA
compiling. `FAST_COMPILE` turns off XLA's CPU fusion emitters, so that fused loops
are emitted by its older elemental emitter: the library's programs compile in less
time and run in the same time (`python benchmarks/latency.py` and
`benchmarks/montecarlo.py` measure both). The option is one of the CPU compiler's.

JAX accepts compiler options only on the outermost compiled program, so
`fast_compile_jit` passes them only where its function is called outside any JAX
transformation. Inside a user's `jit` the function is traced into the user's
program, which compiles with the user's options; under `vmap` or `grad` alone it
compiles as `eqx.filter_jit` does, with XLA's defaults. A user's own programs are
never affected. An XLA that no longer knows the option refuses it at compile time;
the library then compiles every program with XLA's defaults from there on.
"""

import functools
from collections.abc import Callable
from typing import Any, TypeVar, cast

import equinox as eqx
import jax

from ._compat import outside_transformations

_Fn = TypeVar("_Fn", bound=Callable[..., Any])

FAST_COMPILE: dict[str, str | bool | int] = {"xla_cpu_use_fusion_emitters": False}

# False once XLA has refused the options (see the module's docstring).
_options_known = [True]


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
        if _options_known[0] and outside_transformations():
            try:
                return outermost(*args, **kwargs)
            except jax.errors.JaxRuntimeError as err:
                if not _refuses_options(err):
                    raise
                _options_known[0] = False
        return nested(*args, **kwargs)

    def lower(*args: Any, **kwargs: Any) -> Any:  # as filter_jit's
        jitted = outermost if _options_known[0] else nested
        return jitted.lower(*args, **kwargs)  # type: ignore[union-attr]

    call.lower = lower  # type: ignore[attr-defined]
    return cast(_Fn, call)


def _refuses_options(err: Exception) -> bool:
    """Whether `err` is XLA refusing one of `FAST_COMPILE`'s options by name
    (raised when compiling, before anything runs)."""
    text = str(err)
    return "No such compile option" in text and any(k in text for k in FAST_COMPILE)
