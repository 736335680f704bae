"""`filter_jit`, with XLA options that shorten compilation: first-call latency.

In a fresh process the first `simulate` and the first scenario load are mostly XLA
compiling. `FAST_COMPILE` turns off XLA's CPU fusion emitters, so that fused loops
are emitted by its older elemental emitter, and sets XLA's backend optimisation
level to 1 (of 3): the library's programs compile in less time and run in the same
time (`python benchmarks/compile_options.py` measures both, beside XLA's defaults).
They are passed where JAX's default backend is the CPU, whose compiler they were
measured with.

JAX accepts compiler options only on the outermost compiled program, so
`fast_compile_jit` passes them only where its function is called outside any JAX
transformation. Inside a user's `jit` the function is traced into the user's
program, which compiles with the user's options; under `vmap` or `grad` alone it
compiles as `eqx.filter_jit` does, with XLA's defaults. A user's own programs are
never affected. An XLA that no longer knows either option refuses it at compile
time; the library then compiles every program with XLA's defaults from there on.
"""

import functools
from collections.abc import Callable
from typing import Any, TypeVar, cast

import equinox as eqx
import jax

from ._compat import outside_transformations

_Fn = TypeVar("_Fn", bound=Callable[..., Any])

FAST_COMPILE: dict[str, str | bool | int] = {
    "xla_cpu_use_fusion_emitters": False,
    "xla_backend_optimization_level": 1,
}
# XLA's own values of the options `FAST_COMPILE` sets (what a program gets
# without them; the tests and `benchmarks/compile_options.py` compare with these).
XLA_DEFAULTS: dict[str, str | bool | int] = {
    "xla_cpu_use_fusion_emitters": True,
    "xla_backend_optimization_level": 3,
}

# False once XLA has refused the options (see the module's docstring).
_options_known = [True]


def fast_compile_options() -> dict[str, str | bool | int]:
    """`FAST_COMPILE` where JAX's default backend is the CPU, whose compiler the
    options were measured with; none on another backend."""
    return FAST_COMPILE if jax.default_backend() == "cpu" else {}


def fast_compile_jit(fn: _Fn) -> _Fn:
    """`eqx.filter_jit(fn)`, compiled with `fast_compile_options()` when called
    outside any JAX transformation (and inlined into the caller's program
    otherwise, as `eqx.filter_jit` is)."""
    nested = eqx.filter_jit(fn)

    @functools.cache  # (made at the first call: the backend is not known before)
    def outermost_jit() -> Any:
        # `filter_jit` passes further keywords on to `jax.jit` (its typed
        # overloads do not list them).
        return eqx.filter_jit(fn, compiler_options=fast_compile_options())  # type: ignore[call-overload]

    @functools.wraps(fn)
    def call(*args: Any, **kwargs: Any) -> Any:
        if _options_known[0] and outside_transformations():
            try:
                return outermost_jit()(*args, **kwargs)
            except jax.errors.JaxRuntimeError as err:
                if not _refuses_options(err):
                    raise
                _options_known[0] = False
        return nested(*args, **kwargs)

    def lower(*args: Any, **kwargs: Any) -> Any:  # as filter_jit's
        jitted = outermost_jit() if _options_known[0] else nested
        return jitted.lower(*args, **kwargs)  # type: ignore[union-attr]

    call.lower = lower  # type: ignore[attr-defined]
    return cast(_Fn, call)


def _refuses_options(err: Exception) -> bool:
    """Whether `err` is XLA refusing one of `FAST_COMPILE`'s options by name
    (raised when compiling, before anything runs)."""
    text = str(err)
    return "No such compile option" in text and any(k in text for k in FAST_COMPILE)
