"""Uncertain parameters: which leaf of the inputs varies, and how."""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp

from .._forces import AbstractForce, ConstantForce, SampledForce
from .._models import AbstractElasticModel
from .distributions import AbstractDistribution

TARGETS = ("model", "forces", "y_init", "ydot_init")
# Names of the results' own variables and of their labelled axes (and the `_wrt`
# axes of `local_sensitivities`): a parameter or output of one of these names
# would clash with them in the results' dataset.
_AXES = ("time", "body", "coordinate", "connection")
_RESERVED = ("sample", "status", "event_time", *_AXES, *(f"{a}_wrt" for a in _AXES))


class Inputs(eqx.Module):
    """The nominal inputs of `simulate` that a study perturbs."""

    model: AbstractElasticModel
    y_init: jax.Array
    ydot_init: jax.Array
    forces: AbstractForce | None


class Parameter(eqx.Module):
    """One uncertain leaf of the inputs and its distribution.

    **Arguments:**

    - `name`: the variable's name in the results (e.g. `"stiffness"`).
    - `where`: selects the leaf, `equinox.tree_at`-style, from the `target`: e.g.
      `lambda m: m.stiffness`, `lambda m: m.bodies.mass`, `lambda f: f.F` for a
      `ConstantForce` or the samples of a `SampledForce` (the default for
      `target="forces"`). `None` for
      `target="y_init"`/`"ydot_init"` (the whole state array).
    - `distribution`: an `AbstractDistribution`; its parameters broadcast to the
      leaf's shape.
    - `target`: `"model"` (default), `"forces"`, `"y_init"` or `"ydot_init"`.
    - `relative`: when true the leaf becomes (nominal value) x (sample), so
      `LogNormal(0.0, 0.1)` scatters every entry by about 10 % around its own
      nominal value.
    - `dims`: names of the leaf's axes in the results (default `name_0, name_1`...).
    """

    name: str = eqx.field(static=True)
    where: Callable | None = eqx.field(static=True)
    distribution: AbstractDistribution
    target: str = eqx.field(static=True)
    relative: bool = eqx.field(static=True)
    dims: tuple[str, ...] | None = eqx.field(static=True)

    def __init__(
        self, name, where, distribution, target="model", relative=False, dims=None
    ):
        if not isinstance(name, str) or not name.isidentifier():
            raise ValueError(f"Parameter.name must be an identifier, got {name!r}")
        if name in _RESERVED:
            raise ValueError(f"Parameter.name {name!r} is reserved; choose another")
        if target not in TARGETS:
            raise ValueError(
                f"Parameter {name!r}: target must be one of {TARGETS}, got {target!r}"
            )
        if target in ("y_init", "ydot_init") and where is not None:
            raise ValueError(
                f"Parameter {name!r}: target {target!r} is one array; pass "
                f"where=None (entries can be held fixed by a zero spread)"
            )
        if target in ("model", "forces") and where is None:
            if target == "model":
                raise ValueError(
                    f"Parameter {name!r}: where must select a model leaf, e.g. "
                    f"lambda m: m.stiffness"
                )
            where = _constant_force_array
        if where is not None and not callable(where):
            raise ValueError(
                f"Parameter {name!r}: where must be callable, got {where!r}"
            )
        if not isinstance(distribution, AbstractDistribution):
            raise ValueError(
                f"Parameter {name!r}: distribution must be an elasticoop "
                f"distribution (Uniform, Normal, LogNormal, TruncatedNormal, Custom), "
                f"got {distribution!r}"
            )
        self.name = name
        self.where = where
        self.distribution = distribution
        self.target = target
        self.relative = bool(relative)
        self.dims = None if dims is None else tuple(str(d) for d in dims)

    def _select(self, inputs: Inputs):
        part = getattr(inputs, self.target)
        return part if self.where is None else self.where(part)

    def nominal(self, inputs: Inputs) -> jax.Array:
        """The leaf's nominal value in `inputs`."""
        return self._select(inputs)

    def apply(self, inputs: Inputs, value) -> Inputs:
        """`inputs` with the leaf replaced by `value` (a sample of the leaf's law;
        multiplied by the nominal value when `relative`)."""
        if self.relative:
            value = self.nominal(inputs) * value
        return eqx.tree_at(self._select, inputs, jnp.asarray(value, jnp.float64))

    def leaf_dims(self, ndim: int) -> tuple[str, ...]:
        if self.dims is None:
            return tuple(f"{self.name}_{k}" for k in range(ndim))
        if len(self.dims) != ndim:
            raise ValueError(
                f"Parameter {self.name!r}: dims {self.dims} do not match the leaf's "
                f"{ndim} axes"
            )
        return self.dims


def _constant_force_array(force):
    """The force array `F` of a `ConstantForce` (or the samples of a
    `SampledForce`): the leaf a `target="forces"` parameter selects by default."""
    if isinstance(force, ConstantForce | SampledForce):
        return force.F
    raise ValueError(
        "a Parameter with target='forces' and where=None needs constant forces "
        "(an (m, 6) array or ConstantForce) or a SampledForce; pass where= for "
        "other force types"
    )
