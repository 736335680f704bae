"""Content digests of a study's parts: what decides a sample's value, hashed.

A sample's value depends on arrays (digested by dtype, shape and bytes), on static
settings (digested by value) and on callables: the outputs, the `where` selectors,
the distributions' samplers and inverse CDFs, the forces. A callable is digested
by what it computes: its jaxpr on abstract arguments
(`equinox.filter_make_jaxpr`), every primitive with its parameters and the arrays
it closes over by value. So two callables with equal digests compute the same
values whatever their names, and a lambda or a closure is digested as reliably as
a named function; a change of its body, of a constant it closes over or of a
global it reads at trace time changes the digest.

What a jaxpr does not show is reported as *unverified*: a Python function called
through `jax.pure_callback`, `jax.debug.callback` or `io_callback` (its code runs
outside the trace), a user function met outside a traced computation, an object
known only by a repr that holds a memory address, a callable that cannot be traced.
Functions of the numerical libraries (jax, numpy, equinox, diffrax, ...) are
digested by their qualified names.
"""

import dataclasses
import enum
import functools
import hashlib
import re
import types
from collections.abc import Callable
from typing import Any

import equinox as eqx
import jax
import numpy as np
from jax.extend.core import ClosedJaxpr, DropVar, Jaxpr, Literal

# Packages whose functions are identified by name (their code is versioned).
LIBRARIES = frozenset(
    (
        "builtins",
        "diffrax",
        "elasticoop",
        "equinox",
        "functools",
        "jax",
        "jaxlib",
        "lineax",
        "math",
        "numpy",
        "operator",
        "optimistix",
        "scipy",
    )
)
# Primitives that call back into Python: their callable is the computation.
_CALLBACKS = ("pure_callback", "io_callback", "debug_callback")
_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")


def _library(module: str | None) -> bool:
    return module is not None and module.split(".")[0] in LIBRARIES


def _callable_name(fn) -> tuple[str | None, str]:
    module = getattr(fn, "__module__", None)
    name = getattr(fn, "__qualname__", None) or getattr(fn, "__name__", None)
    return module, name or type(fn).__qualname__


class Digest:
    """A running SHA-256 of values (`value`) and of computations (`computation`).

    `unverified` lists, in words, what entered the digest by name only and so may
    change without changing the digest."""

    def __init__(self):
        self._sha = hashlib.sha256()
        self.unverified: list[str] = []

    def hexdigest(self) -> str:
        return self._sha.hexdigest()

    def value(self, x, *, callables_traced: bool = False) -> "Digest":
        """Add a value: arrays by content, settings by value, modules and
        dataclasses field by field. `callables_traced`: the callables met are
        digested separately by `computation` (only their place is recorded);
        otherwise a user function met here is unverified."""
        self._value(x, callables_traced)
        return self

    def computation(self, fn: Callable, *args) -> "Digest":
        """Add what `fn(*args)` computes: its jaxpr on `args` (arrays or
        `jax.ShapeDtypeStruct`s; anything else is static), with the constants it
        closes over, and the structure of its result."""
        try:
            jaxpr, out_struct, out_static = eqx.filter_make_jaxpr(fn)(*args)
        except Exception as err:  # any failure of the user's code while tracing
            self.unverified.append(
                f"{_describe_callable(fn)} cannot be traced on abstract inputs "
                f"({type(err).__name__}: {err})"
            )
            self._token("untraceable", _describe_callable(fn))
            return self
        self._jaxpr(jaxpr)
        self._value(out_struct, False)
        self._value(out_static, False)
        return self

    def _token(self, *parts) -> None:
        for part in parts:
            self._sha.update(str(part).encode())
            self._sha.update(b"\x00")

    def _array(self, x) -> None:
        if jax.dtypes.issubdtype(getattr(x, "dtype", None), jax.dtypes.prng_key):
            x = jax.random.key_data(x)
        a = np.ascontiguousarray(np.asarray(x))
        self._token("array", a.dtype.str, a.shape)
        self._sha.update(a.tobytes())

    def _value(self, x, traced: bool) -> None:
        if x is None or isinstance(x, bool | int | float | complex | str | bytes):
            self._token(type(x).__name__, repr(x))
        elif isinstance(x, np.dtype):
            self._token("dtype", x.str)
        elif isinstance(x, jax.ShapeDtypeStruct):
            self._token("struct", x.shape, np.dtype(x.dtype).str)
        elif eqx.is_array(x) or isinstance(x, np.generic):
            self._array(x)
        elif isinstance(x, ClosedJaxpr | Jaxpr):
            self._jaxpr(x)
        elif isinstance(x, tuple | list):
            self._token(type(x).__name__, len(x))
            for item in x:
                self._value(item, traced)
        elif isinstance(x, dict):
            self._token("dict", len(x))
            for key in sorted(x, key=repr):
                self._value(key, traced)
                self._value(x[key], traced)
        elif isinstance(x, enum.Enum):
            self._token("enum", _qualified(type(x)), x.name)
        elif isinstance(x, type):
            self._token("type", _qualified(x))
        elif isinstance(x, types.ModuleType):
            self._token("module", x.__name__)
        elif dataclasses.is_dataclass(x):
            self._token("object", _qualified(type(x)))
            for field in dataclasses.fields(x):
                if field.compare:  # e.g. a name used only in messages is left out
                    self._token("field", field.name)
                    self._value(getattr(x, field.name, None), traced)
        elif isinstance(x, functools.partial):
            self._token("partial")
            self._value(x.func, traced)
            self._value(x.args, traced)
            self._value(x.keywords, traced)
        elif callable(x):
            self._callable(x, traced)
        else:
            self._repr(x)

    def _callable(self, fn, traced: bool) -> None:
        module, name = _callable_name(fn)
        if _library(module):
            self._token("function", module, name)
        elif traced:
            self._token("traced callable")
        else:
            self.unverified.append(
                f"{_describe_callable(fn)} is known by its name only (its code is "
                f"not traced here)"
            )
            self._token("function", module, name)

    def _repr(self, x) -> None:
        text = repr(x)
        if _ADDRESS.search(text):
            self.unverified.append(
                f"an object of type {_qualified(type(x))} is known by its type only"
            )
            text = _ADDRESS.sub("", text)
        self._token("repr", _qualified(type(x)), text)

    def _jaxpr(self, jaxpr) -> None:
        if isinstance(jaxpr, ClosedJaxpr):
            self._token("consts", len(jaxpr.consts))
            for const in jaxpr.consts:
                self._value(const, False)
            jaxpr = jaxpr.jaxpr
        numbers: dict[int, int] = {}

        def var(v) -> None:
            if isinstance(v, Literal):
                self._token("literal", v.aval)
                self._value(v.val, False)
            elif isinstance(v, DropVar):
                self._token("drop", v.aval)
            else:
                self._token("var", numbers.setdefault(id(v), len(numbers)), v.aval)

        self._token("jaxpr", len(jaxpr.constvars), len(jaxpr.invars))
        for v in (*jaxpr.constvars, *jaxpr.invars):
            var(v)
        for eqn in jaxpr.eqns:
            name = eqn.primitive.name
            self._token("eqn", name, len(eqn.invars), len(eqn.outvars))
            for v in eqn.invars:
                var(v)
            for key in sorted(eqn.params):
                self._token("param", key)
                self._param(name, eqn.params[key])
            for v in eqn.outvars:
                var(v)
        self._token("out", len(jaxpr.outvars))
        for v in jaxpr.outvars:
            var(v)

    def _param(self, primitive: str, value: Any) -> None:
        if isinstance(value, ClosedJaxpr | Jaxpr):
            self._jaxpr(value)
        elif isinstance(value, tuple | list):
            self._token(type(value).__name__, len(value))
            for item in value:
                self._param(primitive, item)
        elif primitive in _CALLBACKS and callable(value):
            fn = getattr(value, "callback_func", value)
            module, name = _callable_name(fn)
            if not _library(module):
                self.unverified.append(
                    f"it calls the Python function {module}.{name} through "
                    f"jax {primitive} (code outside the trace)"
                )
            self._token("callback", module, name)
        elif primitive.startswith("custom_") and not isinstance(
            value, bool | int | float | str | type(None)
        ):
            # derivative rules and tree thunks: they do not change values
            self._token("rule")
        else:
            self._value(value, False)


def _qualified(t: type) -> str:
    return f"{t.__module__}.{t.__qualname__}"


def _describe_callable(fn) -> str:
    module, name = _callable_name(fn)
    return f"the function {module}.{name}"


def abstract(tree):
    """`tree` with every array replaced by its `jax.ShapeDtypeStruct`."""
    return jax.tree.map(
        lambda x: jax.ShapeDtypeStruct(x.shape, x.dtype) if eqx.is_array(x) else x,
        tree,
    )
