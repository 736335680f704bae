"""Input checks that name the offending field and value.

Concrete values are checked eagerly and raise `ValueError`; traced values (inside a
user's `jit`/`vmap`/`grad`) are checked with `eqx.error_if`, which raises at run time.
"""

from collections.abc import Sequence
from types import ModuleType
from typing import Any, TypeVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float

from ._custom_types import ArrayInput, Validated

_T = TypeVar("_T")


def is_concrete(*xs: Any) -> bool:
    """True when no leaf of `xs` is a tracer, so values can be inspected in Python."""
    return not any(isinstance(x, jax.core.Tracer) for x in jax.tree.leaves(xs))


def stack(xs: Sequence[ArrayLike]) -> Array:
    """`jnp.stack(xs)`, stacked by NumPy when every element is concrete: models are
    built op by op, and each JAX operation outside `jit` compiles on its first use
    (tens of milliseconds each in a fresh process)."""
    if is_concrete(xs):
        return jnp.asarray(np.stack([np.asarray(x) for x in xs]))
    return jnp.stack(xs)


def _show(value: Any) -> str:
    arr = np.asarray(value)
    if arr.size > 12:
        return f"array of shape {arr.shape}"
    return np.array2string(arr, precision=6, separator=", ")


def as_float_array(
    value: Validated[ArrayInput],
    name: str,
    shape: Sequence[int | None] | None = None,
    *,
    check_traced: bool = True,
) -> Float[np.ndarray, "..."] | Float[Array, "..."]:
    """Convert to a float64 array, checking shape and finiteness.

    `shape` entries of `None` accept any length along that axis. Concrete input
    comes back as a NumPy array (convert with `jnp.asarray` when storing it), traced
    input as a JAX array. `check_traced=False` leaves the finiteness of traced input
    unchecked, for values whose user reports it otherwise (`simulate` reports it in
    `Trajectory.status`, for each element of a batch on its own).
    """
    arr: np.ndarray | Array
    if isinstance(value, jax.core.Tracer):
        if jnp.iscomplexobj(value):
            raise ValueError(f"{name} must be real, got a traced {value.dtype} array")
        arr = value.astype(jnp.float64) if value.dtype != jnp.float64 else value
    else:
        not_numbers = f"{name} must be an array of numbers, got {value!r}"
        try:
            raw = np.asarray(value)
        except (TypeError, ValueError):
            raise ValueError(not_numbers) from None
        if np.iscomplexobj(raw):  # the cast would drop the imaginary part
            raise ValueError(f"{name} must be real, got {_show(raw)}")
        if raw.dtype.kind in "US":  # text, which the cast would read as numbers
            raise ValueError(not_numbers)
        if raw.dtype.kind == "b":  # a mask given where numbers are meant
            raise ValueError(
                f"{name} must be an array of numbers, got an array of booleans of "
                f"shape {raw.shape} (a mask in the place of numbers?)"
            )
        try:
            arr = raw.astype(np.float64)
        except (TypeError, ValueError):
            raise ValueError(not_numbers) from None
    if shape is not None:
        shape = tuple(shape)
        ok = arr.ndim == len(shape) and all(
            s is None or s == a for s, a in zip(shape, arr.shape)
        )
        if not ok:
            axes = ["any" if s is None else str(s) for s in shape]
            want = f"({axes[0]},)" if len(axes) == 1 else "(" + ", ".join(axes) + ")"
            raise ValueError(f"{name} must have shape {want}, got shape {arr.shape}")
    if isinstance(arr, np.ndarray):
        # concrete input: validate with NumPy (no JAX dispatch or compilation)
        return require(arr, np.all(np.isfinite(arr)), f"{name} must be finite", arr)
    if not check_traced:
        return arr
    return require(arr, jnp.all(jnp.isfinite(arr)), f"{name} must be finite", arr)


def xp(*arrays: Any) -> ModuleType:
    """NumPy for concrete arrays, jax.numpy for traced ones."""
    return np if is_concrete(*arrays) else jnp


def require(x: _T, ok: ArrayLike, message: str, shown: Any = None) -> _T:
    """Return `x`, raising `ValueError(message + value)` where `ok` is false.

    With concrete inputs the check happens now; with traced ones through
    `eqx.error_if` (so it also works under `jit` and `vmap`).
    """
    if is_concrete(ok):
        if not bool(np.all(np.asarray(ok))):
            suffix = "" if shown is None else f", got {_show(shown)}"
            raise ValueError(message + suffix)
        return x
    return eqx.error_if(x, jnp.logical_not(jnp.all(ok)), message)


def check_times(
    ts: Validated[ArrayInput], name: str
) -> Float[np.ndarray, " times"] | Float[Array, " times"]:
    """A time grid: a float64 array `(times,)` of at least 2 finite, strictly
    increasing times (NumPy when concrete, JAX when traced; a traced grid is checked
    at run time). Errors name `name` and, when concrete, the first bad sample."""
    ts = as_float_array(ts, name, (None,))
    if ts.shape[0] < 2:
        raise ValueError(f"{name} needs at least 2 times, got {ts.shape[0]}")
    if isinstance(ts, np.ndarray):
        bad = np.nonzero(ts[1:] <= ts[:-1])[0]
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"{name} must be strictly increasing, but {name}[{k}] = {ts[k]} "
                f"and {name}[{k + 1}] = {ts[k + 1]}"
            )
        return ts
    return require(ts, (ts[1:] > ts[:-1]).all(), f"{name} must be strictly increasing")
