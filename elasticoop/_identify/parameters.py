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


def _range_text(t) -> str:
    if isinstance(t, Bounded):
        return f"between {t.lower:g} and {t.upper:g}, exclusive"
    if isinstance(t, Log | Softplus):
        return "values above 0"
    return "finite values"


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
    fit of the same shapes reuses the compiled functions. `entries` names, per
    leaf, the flat positions of its free entries (`None`: all of them); the other
    entries of a leaf keep the model's values.
    """

    indices: tuple[int, ...] = eqx.field(static=True)
    shapes: tuple[tuple[int, ...], ...] = eqx.field(static=True)
    entries: tuple[tuple[int, ...] | None, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)
    transforms: tuple[AbstractTransform, ...]
    structure: jax.tree_util.PyTreeDef = eqx.field(static=True)

    @property
    def counts(self) -> tuple[int, ...]:
        """Number of free entries of each free leaf."""
        return tuple(
            int(np.prod(shape)) if entries is None else len(entries)
            for shape, entries in zip(self.shapes, self.entries)
        )

    @property
    def size(self) -> int:
        return int(sum(self.counts))

    def split(self, flat):
        """Cut a flat vector into one array per free leaf (shaped like the leaf,
        or a flat vector of the free entries where only some are free)."""
        out, start = [], 0
        for shape, entries, n in zip(self.shapes, self.entries, self.counts):
            piece = flat[start : start + n]
            out.append(piece.reshape(shape) if entries is None else piece)
            start += n
        return out

    def values(self, u: jax.Array) -> list:
        """Physical values $p = g(u)$, one array per free leaf."""
        return [t.forward(x) for t, x in zip(self.transforms, self.split(u))]

    def physical(self, u: jax.Array) -> jax.Array:
        """$p = g(u)$ as one flat vector."""
        return jnp.concatenate([v.reshape(-1) for v in self.values(u)])

    def derivative(self, u) -> np.ndarray:
        """$dp_k/du_k$ of each free parameter at the parameter part of `u` (the
        first `size` entries; each transform acts entry by entry)."""
        u = jnp.asarray(u)[: self.size]
        return np.asarray(jax.jacfwd(self.physical)(u)).diagonal()

    def apply(self, model, u: jax.Array):
        """`model` with its free leaves set to $g(u)$."""
        leaves, treedef = jax.tree.flatten(model)
        for index, entries, value in zip(self.indices, self.entries, self.values(u)):
            leaf = jnp.asarray(leaves[index])
            if entries is not None:
                at = jnp.asarray(entries)
                value = leaf.reshape(-1).at[at].set(value).reshape(leaf.shape)
            leaves[index] = value.astype(leaf.dtype)
        return jax.tree.unflatten(treedef, leaves)

    def lower_bounds(self) -> np.ndarray:
        """The lower end of each free parameter's range (one flat vector): 0 for
        `Log` and `Softplus`, $l$ for `Bounded`, $-\\infty$ for `Identity`."""
        out = []
        for t, n in zip(self.transforms, self.counts):
            if isinstance(t, Log | Softplus):
                low = 0.0
            elif isinstance(t, Bounded):
                low = t.lower
            else:
                low = -np.inf
            out.append(np.full(n, low))
        return np.concatenate(out) if out else np.zeros(0)

    def unconstrained(self, p) -> np.ndarray:
        """$u = g^{-1}(p)$ for physical values `p` (one flat vector); a value
        outside its transform's range is a `ValueError` naming the entry (e.g.
        `stiffness[plate-front].x`)."""
        parts, start = [], 0
        for t, x, n in zip(self.transforms, self.split(np.asarray(p)), self.counts):
            flat = np.asarray(x).reshape(-1)
            try:
                parts.append(np.asarray(t.inverse(flat, "")).reshape(-1))
            except ValueError:
                for k in range(flat.size):
                    try:
                        t.inverse(flat[k : k + 1], "")
                    except ValueError:
                        raise ValueError(
                            f"{self.names[start + k]} = {float(flat[k])!r} is "
                            f"outside the range of the {type(t).__name__} "
                            f"reparameterisation ({_range_text(t)}): start it "
                            f"from a value inside "
                            f"that range, or choose another transform"
                        ) from None
                raise
            start += n
        return np.concatenate(parts)

    def current(self, model) -> np.ndarray:
        """The free values of `model` as one flat vector."""
        leaves = jax.tree.leaves(model)
        parts = []
        for index, entries in zip(self.indices, self.entries):
            flat = np.asarray(leaves[index]).reshape(-1)
            parts.append(flat if entries is None else flat[list(entries)])
        return np.concatenate(parts)

    @property
    def leaf_names(self) -> tuple[str, ...]:
        return tuple(n.split("[")[0] for n in self._leaf_first_names())

    def _leaf_first_names(self):
        out, start = [], 0
        for n in self.counts:
            out.append(self.names[start])
            start += n
        return out

    def unflatten(self, flat):
        """A flat vector (e.g. standard errors) in the structure of `where(model)`,
        NaN at the entries that are not free."""
        parts = []
        for shape, entries, x in zip(
            self.shapes, self.entries, self.split(np.asarray(flat))
        ):
            if entries is not None:
                full = np.full(int(np.prod(shape)), np.nan)
                full[list(entries)] = x
                x = full.reshape(shape)
            parts.append(np.asarray(x))
        return jax.tree.unflatten(self.structure, parts)


def free_parameters(
    model, where, transform="log", mask=None, body_names=None
) -> FreeParameters:
    """Resolve `where(model)` into a `FreeParameters`.

    **Arguments:**

    - `model`: the model whose leaves are fitted.
    - `where`: a function returning the free leaves, e.g.
      `lambda m: (m.stiffness, m.damping)`; it must select whole array leaves.
    - `transform`: a name (`"log"`, `"softplus"`, `"identity"`), an
      `AbstractTransform`, or a sequence of these with one entry per selected leaf.
    - `mask`: which entries of the selected leaves are free: `None` (all), or
      boolean arrays in the structure of `where(model)`, each shaped like its
      leaf (`None` in place of an array frees that whole leaf). Entries where the
      mask is False keep the model's values.
    - `body_names`: names of the bodies in the parameters' names (e.g.
      `stiffness[plate-front].x`, `mass[plate]`, `inertia[plate].A`); default:
      their indices (`stiffness[0-1].x`, `bodies.mass[0]`).
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
    entries = _mask_entries(mask, structure, shapes, [paths[i] for i in indices])
    names: list[str] = []
    for index, shape, free in zip(indices, shapes, entries):
        every = _entry_names(model, paths[index].lstrip("."), shape, body_names)
        names += every if free is None else [every[k] for k in free]
    return FreeParameters(
        indices=indices,
        shapes=shapes,
        entries=entries,
        names=tuple(names),
        transforms=transforms,
        structure=structure,
    )


def _mask_entries(mask, structure, shapes, paths):
    """The flat positions of the free entries of each leaf (`None`: all)."""
    if mask is None:
        return tuple(None for _ in shapes)
    try:
        masks = structure.flatten_up_to(mask)
    except (ValueError, TypeError):
        raise ValueError(
            f"mask must have the structure of where(model) ({len(shapes)} leaves: "
            f"one boolean array or None per selected leaf), got {mask!r}"
        ) from None
    out: list[tuple[int, ...] | None] = []
    for m, shape, path in zip(masks, shapes, paths):
        if m is None:
            out.append(None)
            continue
        arr = np.asarray(m)
        if arr.dtype != bool or arr.shape != shape:
            raise ValueError(
                f"mask of {path.lstrip('.')} must be a boolean array of shape "
                f"{shape}, got {arr.dtype} of shape {arr.shape}"
            )
        if not arr.any():
            raise ValueError(
                f"mask of {path.lstrip('.')} frees no entry: leave the leaf out of "
                f"where instead"
            )
        out.append(tuple(int(k) for k in np.flatnonzero(arr.reshape(-1))))
    return tuple(out)


class _Label:
    """Stands in for a model leaf while `where` is resolved."""

    def __init__(self, index):
        self.index = index

    def __repr__(self):
        return f"<leaf {self.index}>"


def _entry_names(model, path, shape, body_names=None):
    """Readable names of the entries of one leaf, e.g. `stiffness[0-1].x`, or with
    `body_names` `stiffness[plate-front].x`."""
    names = list(body_names) if body_names is not None else None
    if isinstance(model, MobileModel) and path in ("stiffness", "damping"):
        pairs = np.asarray(model.pairs)
        coords = coordinate_names(model.convention)
        if names is not None:
            return [
                f"{path}[{names[i]}-{names[j]}].{c}"
                for i, j in pairs.tolist()
                for c in coords
            ]
        return [f"{path}[{i}-{j}].{c}" for i, j in pairs.tolist() for c in coords]
    if names is not None and path == "bodies.mass" and shape == (len(names),):
        return [f"mass[{b}]" for b in names]
    if names is not None and path == "bodies.inertia" and shape == (len(names), 3):
        return [f"inertia[{b}].{a}" for b in names for a in "ABC"]
    if not shape:
        return [path]
    return [
        f"{path}[{', '.join(str(int(k)) for k in idx)}]" for idx in np.ndindex(*shape)
    ]
