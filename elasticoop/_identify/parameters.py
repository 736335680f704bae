"""Free parameters: which leaves of the model are fitted, and in which coordinates.

The optimiser works on an unconstrained vector $u$; each free leaf is
$p = g(u)$ with $g$ a fixed reparameterisation (`Log`: $p = e^u > 0$, `Softplus`:
$p = \\log(1 + e^u) > 0$, `Bounded`: $p = l + (h - l)\\,\\sigma(u) \\in (l, h)$,
`Identity`). Positivity and bounds hold by construction, never by clipping.
"""

import abc
from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._models import MobileModel
from .._naming import coordinate_names


class AbstractTransform(eqx.Module):
    """A reparameterisation $p = g(u)$ of one free leaf (elementwise)."""

    @abc.abstractmethod
    def forward(self, u: jax.Array) -> jax.Array:
        """$p = g(u)$."""

    @abc.abstractmethod
    def inverse(self, p: np.ndarray, name: str) -> np.ndarray:
        """$u = g^{-1}(p)$, raising `ValueError` naming `name` outside the range."""


class Identity(AbstractTransform):
    """$p = u$ (unconstrained)."""

    def forward(self, u):
        return u

    def inverse(self, p, name):
        return p


class Log(AbstractTransform):
    """$p = e^u$: positive, and steps in $u$ are relative steps in $p$."""

    def forward(self, u):
        return jnp.exp(u)

    def inverse(self, p, name):
        _check_range(p, 0.0, np.inf, name, "Log")
        return np.log(p)


class Softplus(AbstractTransform):
    """$p = \\log(1 + e^u)$: positive, linear for large $p$."""

    def forward(self, u):
        return jax.nn.softplus(u)

    def inverse(self, p, name):
        _check_range(p, 0.0, np.inf, name, "Softplus")
        return p + np.log(-np.expm1(-p))


class Bounded(AbstractTransform):
    """$p = l + (h - l)\\,\\sigma(u)$, $\\sigma$ the logistic function: $l < p < h$."""

    lower: float
    upper: float

    def __init__(self, lower, upper):
        if not (np.isfinite(lower) and np.isfinite(upper) and lower < upper):
            raise ValueError(
                f"Bounded needs finite lower < upper, got ({lower}, {upper})"
            )
        self.lower, self.upper = float(lower), float(upper)

    def forward(self, u):
        return self.lower + (self.upper - self.lower) * jax.nn.sigmoid(u)

    def inverse(self, p, name):
        _check_range(p, self.lower, self.upper, name, "Bounded")
        s = (p - self.lower) / (self.upper - self.lower)
        return np.log(s) - np.log1p(-s)


def _check_range(p, lower, upper, name, what):
    bad = ~((p > lower) & (p < upper))
    if np.any(bad):
        k = tuple(int(i) for i in np.argwhere(bad)[0])
        raise ValueError(
            f"{name}{list(k) if k else ''} = {p[k]} is outside the range "
            f"({lower}, {upper}) of the {what} reparameterisation: start from a "
            f"value inside it or choose another transform"
        )


_NAMED: dict[str, Callable[[], AbstractTransform]] = {
    "log": Log,
    "softplus": Softplus,
    "identity": Identity,
}


def as_transform(value) -> AbstractTransform:
    if isinstance(value, AbstractTransform):
        return value
    if isinstance(value, str) and value in _NAMED:
        return _NAMED[value]()
    raise ValueError(
        f"transform must be one of {sorted(_NAMED)} or an AbstractTransform "
        f"(e.g. Bounded(lower, upper)), got {value!r}"
    )


class FreeParameters(eqx.Module):
    """The free leaves of a model and their reparameterisations.

    Built once from `where` (a function selecting leaves, as for
    `equinox.tree_at`); afterwards the free leaves are addressed by their position
    in `jax.tree.leaves(model)`, so nothing here holds `where` itself and a second
    fit of the same shapes reuses the compiled functions.
    """

    indices: tuple[int, ...] = eqx.field(static=True)
    shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    transforms: tuple[AbstractTransform, ...]
    structure: jax.tree_util.PyTreeDef = eqx.field(static=True)

    @property
    def size(self) -> int:
        return int(sum(int(np.prod(s)) for s in self.shapes))

    def split(self, flat):
        """Cut a flat vector into one array per free leaf."""
        out, start = [], 0
        for shape in self.shapes:
            n = int(np.prod(shape))
            out.append(flat[start : start + n].reshape(shape))
            start += n
        return out

    def values(self, u: jax.Array) -> list:
        """Physical values $p = g(u)$, one array per free leaf."""
        return [t.forward(x) for t, x in zip(self.transforms, self.split(u))]

    def physical(self, u: jax.Array) -> jax.Array:
        """$p = g(u)$ as one flat vector."""
        return jnp.concatenate([v.reshape(-1) for v in self.values(u)])

    def apply(self, model, u: jax.Array):
        """`model` with its free leaves set to $g(u)$."""
        leaves, treedef = jax.tree.flatten(model)
        for index, value in zip(self.indices, self.values(u)):
            leaves[index] = value.astype(leaves[index].dtype)
        return jax.tree.unflatten(treedef, leaves)

    def unconstrained(self, p) -> np.ndarray:
        """$u = g^{-1}(p)$ for physical values `p` (one flat vector)."""
        parts = [
            t.inverse(np.asarray(x), name).reshape(-1)
            for t, x, name in zip(
                self.transforms, self.split(np.asarray(p)), self.leaf_names
            )
        ]
        return np.concatenate(parts)

    def current(self, model) -> np.ndarray:
        """The free values of `model` as one flat vector."""
        leaves = jax.tree.leaves(model)
        return np.concatenate([np.asarray(leaves[i]).reshape(-1) for i in self.indices])

    @property
    def leaf_names(self) -> tuple[str, ...]:
        return tuple(n.split("[")[0] for n in self._leaf_first_names())

    def _leaf_first_names(self):
        out, start = [], 0
        for shape in self.shapes:
            out.append(self.names[start])
            start += int(np.prod(shape))
        return out

    def unflatten(self, flat):
        """A flat vector (e.g. standard errors) in the structure of `where(model)`."""
        return jax.tree.unflatten(
            self.structure, [np.asarray(x) for x in self.split(np.asarray(flat))]
        )


def free_parameters(model, where, transform="log") -> FreeParameters:
    """Resolve `where(model)` into a `FreeParameters`.

    **Arguments:**

    - `model`: the model whose leaves are fitted.
    - `where`: a function returning the free leaves, e.g.
      `lambda m: (m.stiffness, m.damping)`; it must select whole array leaves.
    - `transform`: a name (`"log"`, `"softplus"`, `"identity"`), an
      `AbstractTransform`, or a sequence of these with one entry per selected leaf.
    """
    if not callable(where):
        raise ValueError(
            f"where must be a function selecting model leaves, e.g. "
            f"lambda m: (m.stiffness, m.damping), got {where!r}"
        )
    leaves, treedef = jax.tree.flatten(model)
    labels = jax.tree.unflatten(treedef, [_Label(k) for k in range(len(leaves))])
    try:
        picked = where(labels)
    except Exception as error:
        raise ValueError(
            "where must select whole leaves of the model by attribute access, e.g. "
            f"lambda m: (m.stiffness, m.damping); calling it failed with: {error!r}"
        ) from None
    chosen, structure = jax.tree.flatten(
        picked, is_leaf=lambda x: isinstance(x, _Label)
    )
    if not chosen or not all(isinstance(x, _Label) for x in chosen):
        raise ValueError(
            "where must return model leaves (arrays), e.g. "
            f"lambda m: (m.stiffness, m.damping); got {picked!r}"
        )
    indices = tuple(x.index for x in chosen)
    if len(set(indices)) != len(indices):
        raise ValueError("where selects the same leaf twice")
    paths = [
        jax.tree_util.keystr(p) for p, _ in jax.tree_util.tree_leaves_with_path(model)
    ]
    for index in indices:
        leaf = leaves[index]
        if not jnp.issubdtype(jnp.asarray(leaf).dtype, jnp.floating):
            raise ValueError(
                f"where selects the model leaf {paths[index].lstrip('.')}, which is "
                f"not a floating-point array and cannot be fitted"
            )
        if jnp.size(leaf) == 0:
            raise ValueError(f"where selects the empty leaf {paths[index].lstrip('.')}")
    if isinstance(transform, str | AbstractTransform):
        transforms = tuple(as_transform(transform) for _ in indices)
    else:
        transform = list(transform)
        if len(transform) != len(indices):
            raise ValueError(
                f"transform has {len(transform)} entries but where selects "
                f"{len(indices)} leaves"
            )
        transforms = tuple(as_transform(t) for t in transform)
    shapes = tuple(tuple(int(s) for s in np.shape(leaves[i])) for i in indices)
    names = []
    for index, shape in zip(indices, shapes):
        names += _entry_names(model, paths[index].lstrip("."), shape)
    return FreeParameters(
        indices=indices,
        shapes=shapes,
        names=tuple(names),
        transforms=transforms,
        structure=structure,
    )


class _Label:
    """Stands in for a model leaf while `where` is resolved."""

    def __init__(self, index):
        self.index = index

    def __repr__(self):
        return f"<leaf {self.index}>"


def _entry_names(model, path, shape):
    """Readable names of the entries of one leaf, e.g. `stiffness[0-1].x`."""
    if isinstance(model, MobileModel) and path in ("stiffness", "damping"):
        pairs = np.asarray(model.pairs)
        coords = coordinate_names(model.convention)
        return [f"{path}[{i}-{j}].{c}" for i, j in pairs.tolist() for c in coords]
    if not shape:
        return [path]
    return [
        f"{path}[{', '.join(str(int(k)) for k in idx)}]" for idx in np.ndindex(*shape)
    ]
