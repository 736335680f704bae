"""The places where elasticoop relies on private details of its dependencies.

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
import re

import equinox
import jax
import jax.extend.core

# The equinox versions this module supports: from the first up to, excluding, the
# second.
SUPPORTED_EQUINOX = ((0, 11, 10), (0, 14, 0))

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
