"""Traced programs kept on disk, so that a fresh process need not trace them again.

JAX's persistent compilation cache (`_cache`) saves XLA's compilation only: a
fresh process still traces each program in Python and lowers it, to find the
program's cache key. For the static equilibrium that loading a scenario solves
(optimistix's BFGS and Levenberg-Marquardt around the model's forces), tracing
and lowering are most of what `elasticoop check` does.

`stored_program(fn)` keeps the lowered program of `fn` (a `fast_compile_jit`
function) in the compilation cache folder, serialized with `jax.export`, under a
key made of everything the trace depends on: the function, the structure and the
static (non-array) values of its arguments, the shape and dtype of each array, the
source files of elasticoop, the versions of jax, jaxlib, equinox, optimistix and
lineax, JAX's 64-bit mode and equinox's error mode. A later call with the same key
loads the program instead of tracing `fn`, and compiles it with the same XLA
options (a compilation the persistent cache holds from the first call): the same
program, so the same numbers.

It works only while the compilation cache is in use (the command line, or
`enable_compilation_cache`), only outside JAX transformations, and only where the
arguments' static values have a faithful text form; anything else, and any failure
to store or load a program (the program then is simply traced, as without the
cache), calls `fn` as it is.
"""

import contextlib
import functools
import hashlib
import importlib.metadata
import os
import pathlib
import re
import sys
import tempfile
from collections.abc import Callable
from typing import Any, TypeVar, cast

import equinox as eqx
import jax
import numpy as np

from ._cache import active_cache_folder
from ._compat import outside_transformations
from ._compile_options import fast_compile_options
from ._version import __version__

_Fn = TypeVar("_Fn", bound=Callable[..., Any])

# The subfolder of the compilation cache folder that holds the programs.
FOLDER = "traces"
# The distributions whose code a stored program may contain.
_DISTRIBUTIONS = ("jax", "jaxlib", "equinox", "optimistix", "lineax")
# The programs this process has loaded or stored, compiled on first use.
_programs: dict[pathlib.Path, Callable[..., Any]] = {}


def stored_program(fn: _Fn) -> _Fn:
    """`fn`, a compiled function of arrays and static values whose result is a
    tuple of arrays, with its traced program kept on disk (see the module's
    docstring)."""

    @functools.wraps(fn)
    def call(*args: Any) -> Any:
        folder = active_cache_folder()
        if folder is None or not outside_transformations():
            return fn(*args)
        dynamic, static = eqx.partition(args, eqx.is_array)
        leaves, dynamic_tree = jax.tree_util.tree_flatten(dynamic)
        key = _key(fn, static, dynamic_tree, leaves)
        if key is None:
            return fn(*args)
        path = pathlib.Path(folder) / FOLDER / f"{key}.jaxexport"
        program = _programs.get(path)
        if program is None:
            exported = _load(path)
            if exported is None:

                def flat(*arrays: Any) -> Any:
                    tree = jax.tree_util.tree_unflatten(dynamic_tree, arrays)
                    return fn(*eqx.combine(tree, static))

                exported = _export(flat, leaves)
                if exported is None:
                    return fn(*args)
                _store(path, exported)
            _initialise_lapack(exported)
            program = jax.jit(exported.call, compiler_options=fast_compile_options())
            _programs[path] = program
        try:
            return program(*leaves)
        except jax.errors.JaxRuntimeError:  # e.g. an XLA that refuses the options
            _programs.pop(path, None)
            return fn(*args)

    return cast(_Fn, call)


def _key(fn: Callable, static: Any, dynamic_tree: Any, leaves: list) -> str | None:
    """The key of a program, or `None` where the arguments hold code that the key
    does not cover (a class or function of the caller's own: its source is not
    hashed), or a static value whose text form is not faithful (an object shown by
    its address)."""
    static_leaves, static_tree = jax.tree_util.tree_flatten(static)
    if not (_known_structure(static_tree) and _known_structure(dynamic_tree)):
        return None
    if not all(_known_value(v) for v in static_leaves):
        return None
    code = _code_version()
    if code is None:
        return None
    described = "\n".join(
        [
            f"{fn.__module__}.{fn.__qualname__}",
            repr(static_tree),
            repr(static_leaves),
            repr(dynamic_tree),
            repr(
                [
                    (np.shape(x), str(x.dtype), bool(getattr(x, "weak_type", False)))
                    for x in leaves
                ]
            ),
            repr(sorted(fast_compile_options().items())),
            f"x64={jax.config.read('jax_enable_x64')}",
            f"equinox errors={_equinox_error_mode()}",
            f"backend={jax.default_backend()}",
            code,
        ]
    )
    if re.search(r" at 0x[0-9a-f]+", described):
        return None
    return hashlib.sha256(described.encode()).hexdigest()


# Where the classes and functions in a key may come from: elasticoop (its sources
# are hashed), the libraries whose versions are in the key, and Python itself.
_KNOWN_MODULES = ("elasticoop", "equinox", "jax", "jaxlib", "builtins", "collections")


def _known_structure(treedef: Any) -> bool:
    """Whether every node of `treedef` (its class and auxiliary data: an equinox
    Module's static fields) is made of known code."""
    stack = [treedef]
    while stack:
        node = stack.pop()
        data = node.node_data()
        if data is not None and not _known_value(data):
            return False
        stack.extend(node.children())
    return True


def _known_value(value: Any) -> bool:
    """Whether `value` is a plain value, a container of them, or a class, function
    or object of known code (see `_KNOWN_MODULES`)."""
    if value is None or isinstance(value, bool | int | float | complex | str | bytes):
        return True
    if isinstance(value, tuple | list | frozenset | set):
        return all(_known_value(v) for v in value)
    if isinstance(value, dict):
        return all(_known_value(k) and _known_value(v) for k, v in value.items())
    if isinstance(value, type) or callable(value):
        module = getattr(value, "__module__", None) or ""
    else:
        module = type(value).__module__
    return module.split(".")[0] in _KNOWN_MODULES


def _equinox_error_mode() -> str:
    errors = sys.modules.get("equinox._errors")
    return str(getattr(errors, "EQX_ON_ERROR", "unknown"))


@functools.cache
def _code_version() -> str | None:
    """A digest of elasticoop's source files and the versions of the libraries
    whose code a program contains (`None` where the sources cannot be read)."""
    digest = hashlib.sha256(__version__.encode())
    package = pathlib.Path(__file__).parent
    sources = sorted(package.rglob("*.py"))
    if not sources:
        return None
    for path in sources:
        digest.update(str(path.relative_to(package)).encode())
        digest.update(path.read_bytes())
    versions = []
    for name in _DISTRIBUTIONS:
        try:
            versions.append(f"{name}={importlib.metadata.version(name)}")
        except importlib.metadata.PackageNotFoundError:
            versions.append(f"{name}=none")
    return f"elasticoop sources {digest.hexdigest()}; " + ", ".join(versions)


def _export(flat: Callable, leaves: list) -> Any:
    """`flat` traced and lowered as a `jax.export.Exported`, or `None` where it
    cannot be (e.g. a host callback). The program is loaded only by the same
    versions of jax and jaxlib (they are in its key), so custom calls without
    compatibility guarantees across versions (LAPACK's, on CPU) are allowed."""
    jitted = jax.jit(flat)
    try:
        text = jitted.lower(*leaves).as_text()
        targets = sorted(set(re.findall(r"custom_call @([\w.]+)", text)))
        checks = [jax.export.DisabledSafetyCheck.custom_call(t) for t in targets]
        return jax.export.export(jitted, disabled_checks=checks)(*leaves)
    except Exception:  # not exportable: traced as it is
        return None


def _store(path: pathlib.Path, exported: Any) -> None:
    """Write the program atomically; a folder that cannot take it is left alone."""
    with contextlib.suppress(Exception):
        data = exported.serialize()
        path.parent.mkdir(parents=True, exist_ok=True)
        handle, temporary = tempfile.mkstemp(dir=path.parent, suffix=".partial")
        try:
            with os.fdopen(handle, "wb") as file:
                file.write(data)
            os.replace(temporary, path)
        finally:
            with contextlib.suppress(FileNotFoundError):
                os.unlink(temporary)


def _load(path: pathlib.Path) -> Any:
    """The stored program, or `None` if there is none or it cannot be read."""
    try:
        data = path.read_bytes()
    except OSError:
        return None
    try:
        return jax.export.deserialize(bytearray(data))
    except Exception:  # damaged: traced again and stored anew
        return None


def _initialise_lapack(exported: Any) -> None:
    """JAX loads LAPACK (from SciPy) when it lowers the first program that calls it,
    not when it runs one: a loaded program that calls LAPACK is preceded by the
    lowering of a small one that does."""
    if b"lapack_" in exported.mlir_module_serialized:
        _lower_a_lapack_call()


@functools.cache
def _lower_a_lapack_call() -> None:
    jax.jit(jax.numpy.linalg.qr).lower(np.zeros((2, 2)))
