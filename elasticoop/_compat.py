"""The places where elasticoop relies on private details of its dependencies.

diffrax (read in 0.7.0 to 0.7.2; `SUPPORTED_DIFFRAX`, and pyproject.toml's bound):
the dense output of its explicit Runge-Kutta solvers is built by the solver's
`interpolation_cls(t0=, t1=, y0=, y1=, k=)` from the stage increments that its
`step` returns as `dense_info["k"]` (`dense_interpolation`, `dense_stages`), and
`diffeqsolve` wraps every term before its step-size controller's `init` sees it,
which changes the first step the controller picks (`wrapped_term`). The engine's
tests (`tests/test_batch_loop.py`, `tests/test_stepwise_adjoint.py`) compare what
relies on these with diffrax's own loop and adjoint.

equinox's runtime checks (`equinox.error_if`, which diffrax, optimistix and lineax
use inside compiled code) compile to host callbacks in equinox's default mode,
`"raise"`, and JAX never stores an executable that contains a host callback in its
persistent compilation cache. In `"nan"` mode a failed check returns NaN instead,
with no callback, so the executable can be stored. The public switch is the
environment variable `EQX_ON_ERROR`, but equinox reads it once, when it is
imported, which is too late for a program that has already imported elasticoop.
So this module sets the module global that equinox reads each time it traces a
check, `equinox._errors.EQX_ON_ERROR`.

That global exists, with this meaning, in equinox 0.11.10 to 0.13.8 (read in their
sources; the tests exercise the installed version). Outside `SUPPORTED_EQUINOX`
this module raises `RuntimeError` rather than guess.

`outside_transformations` tells whether a JAX transformation is tracing the caller
from the class of JAX's current trace (`jax.extend.core.find_top_trace`), whose
name, `EvalTrace`, is not public; were it renamed, the function would answer False
everywhere and the library's programs would compile as plain `eqx.filter_jit`
(`tests/test_compile_options.py` checks both answers).
"""

import contextlib
import functools
import re
from typing import TYPE_CHECKING, Any

import equinox
import jax
import jax.extend.core
import jax.numpy as jnp

# diffrax is imported where a run needs it (checking a scenario does not).
if TYPE_CHECKING:
    import diffrax

    Solver = diffrax.AbstractSolver
    Interpolation = diffrax.AbstractLocalInterpolation
    Term = diffrax.AbstractTerm
else:  # what runtime type checks see
    Solver = Interpolation = Term = Any

# The equinox versions this module supports: from the first up to, excluding, the
# second.
SUPPORTED_EQUINOX = ((0, 11, 10), (0, 14, 0))
# The diffrax versions whose private details below were read: from the first up to,
# excluding, the second (pyproject.toml bounds the dependency the same).
SUPPORTED_DIFFRAX = ((0, 7, 0), (0, 8, 0))

MODES = ("raise", "nan", "off")

# The mode is no part of JAX's cache keys, so functions traced inside
# `equinox_error_mode` are keyed by this context as well: none of them is reused
# outside the block, in the wrong mode.
_make_user_context = getattr(jax, "make_user_context", None)
_TRACE_KEY = None if _make_user_context is None else _make_user_context(None)


def _version(text: str) -> tuple[int, int, int]:
    numbers = re.match(r"(\d+)\.(\d+)(?:\.(\d+))?", text)
    if numbers is None:
        return (0, 0, 0)
    major, minor, patch = numbers.groups()
    return (int(major), int(minor), int(patch or 0))


def check_equinox_version(version: str | None = None) -> None:
    """Raise `RuntimeError` unless `version` (default: the installed equinox's) is
    within `SUPPORTED_EQUINOX`."""
    version = equinox.__version__ if version is None else version
    first, end = SUPPORTED_EQUINOX
    if not first <= _version(version) < end:
        supported = f">={'.'.join(map(str, first))},<{'.'.join(map(str, end))}"
        raise RuntimeError(
            f"elasticoop's compilation cache supports equinox{supported}, but "
            f"equinox {version} is installed: install a supported version "
            f"(pip install 'equinox{supported}')"
        )


def _errors_module():
    check_equinox_version()
    import equinox._errors

    return equinox._errors


def set_equinox_error_mode(mode: str) -> str:
    """Trace equinox's runtime checks in `mode` (`"raise"`, `"nan"` or `"off"`)
    from now on, in the whole process; returns the previous mode. Functions
    already traced keep the mode they were traced in."""
    if mode not in MODES:
        raise ValueError(f"mode must be one of {MODES}, got {mode!r}")
    errors = _errors_module()
    previous = errors.EQX_ON_ERROR
    errors.EQX_ON_ERROR = mode
    return previous


@contextlib.contextmanager
def equinox_error_mode(mode: str):
    """`set_equinox_error_mode` for the duration of a `with` block. Afterwards the
    previous mode is back, and no function traced inside runs in `mode` (they are
    cached apart from those traced outside). Not for several threads at once."""
    previous = set_equinox_error_mode(mode)
    try:
        if _TRACE_KEY is None:  # a JAX without user contexts
            yield
        else:
            with _TRACE_KEY(mode):
                yield
    finally:
        _errors_module().EQX_ON_ERROR = previous
        if _TRACE_KEY is None:
            jax.clear_caches()


def outside_transformations() -> bool:
    """True when no JAX transformation (`jit`, `vmap`, `grad`, ...) is tracing the
    caller: a program compiled from here is the outermost one."""
    return type(jax.extend.core.find_top_trace(())).__name__ == "EvalTrace"


def check_diffrax_version(version: str | None = None) -> None:
    """Raise `RuntimeError` unless `version` (default: the installed diffrax's) is
    within `SUPPORTED_DIFFRAX`."""
    if version is None:
        import diffrax

        version = diffrax.__version__
    first, end = SUPPORTED_DIFFRAX
    if not first <= _version(version) < end:
        supported = f">={'.'.join(map(str, first))},<{'.'.join(map(str, end))}"
        raise RuntimeError(
            f"elasticoop's engine supports diffrax{supported}, but diffrax {version} "
            f"is installed: install a supported version (pip install "
            f"'diffrax{supported}')"
        )


def dense_interpolation(
    solver: Solver, t0: Any, t1: Any, y0: Any, y1: Any, k: Any
) -> Interpolation:
    """The dense output of one step of an explicit Runge-Kutta `solver` from `t0`
    to `t1`, from its ends `y0`, `y1` and stage increments `k`."""
    return solver.interpolation_cls(  # type: ignore[attr-defined]
        t0=t0, t1=t1, y0=y0, y1=y1, k=k
    )


def dense_stages(solver: Any) -> int | None:
    """How many stage increments the solver's dense output holds (its `k`), or
    `None` if its dense output is not built from them."""
    import diffrax

    term = diffrax.ODETerm(lambda t, y, args: -y)
    y0 = jnp.zeros(1)

    def step():
        state = solver.init(term, 0.0, 1.0, y0, None)
        return solver.step(term, 0.0, 1.0, y0, None, state, False)[2]

    try:
        dense = jax.eval_shape(step)
    except Exception:  # not a solver of this kind
        return None
    k = dense.get("k") if isinstance(dense, dict) else None
    return None if k is None else int(k.shape[0])


@functools.cache
def _wrapped_class() -> type:
    """The wrapper class of `wrapped_term` (one class: defined on first use)."""
    import diffrax

    class _Wrapped(diffrax.AbstractTerm):
        term: diffrax.AbstractTerm

        def vf(self, t, y, args):
            return self.term.vf(t, y, args)

        def contr(self, t0, t1, **kwargs):
            return self.term.contr(t0, t1, **kwargs)

        def prod(self, vf, control):
            return self.term.prod(vf, control)

    return _Wrapped


def wrapped_term(term: Term) -> Term:
    """`term` as `diffrax.diffeqsolve` hands it to the step-size controller's
    `init`: wrapped (diffrax wraps every term in its time direction), so that the
    controller picks the same first step as there (diffrax 0.7 estimates one for an
    `ODETerm` only, and tries 0.01 for any other term)."""
    return _wrapped_class()(term)
