"""Appendix B: the mobile unloaded state, pairwise springs with rest length."""

import functools
import operator
from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._body import RigidBody, stack_bodies
from .._custom_types import (
    BoolScalar,
    DofMatrix,
    Pairs,
    Scalar,
    State,
    Vector3,
    Vector6,
)
from .._rotations import get_rotation
from .._validation import as_float_array, is_concrete, require, stack, xp
from .base import AbstractElasticModel
from .immobile import check_gravity


class Connection(eqx.Module):
    """One elastic connection between bodies `i` and `j` (Appendix B).

    **Arguments:**

    - `i`, `j`: body indices (0 is the object), `i != j`.
    - `stiffness`: $(c^x, c^y, c^z, c^{a_1}, c^{a_2}, c^{a_3})$, $\\ge 0$
      [N/m, N m/rad].
    - `damping`: the six diagonal entries of $D^\\delta$ and $D^{\\mathcal A}$,
      $\\ge 0$ [N s/m, N m s/rad].
    - `rest_length`: $\\rho_{ij0} \\ge 0$ [m], the unloaded length of the link.
    - `rest_angles`: $\\Delta\\mathcal{A}_{ij0}$ [rad], the unloaded difference of
      Euler angles $\\mathcal{A}_i - \\mathcal{A}_j$ (the appendix takes 0).
    """

    i: int = eqx.field(static=True)
    j: int = eqx.field(static=True)
    stiffness: Vector6
    damping: Vector6
    rest_length: Scalar
    rest_angles: Vector3

    def __init__(
        self, i, j, stiffness, damping, rest_length=0.0, rest_angles=(0, 0, 0)
    ):
        for name, value in (("i", i), ("j", j)):
            if isinstance(value, bool) or not isinstance(value, int | np.integer):
                raise ValueError(
                    f"Connection.{name} must be a body index, got {value!r}"
                )
            if value < 0:
                raise ValueError(f"Connection.{name} must be >= 0, got {value}")
        if i == j:
            raise ValueError(
                f"Connection must join two different bodies, got i = j = {i}"
            )
        self.i, self.j = int(i), int(j)
        label = f"Connection({i}, {j})"
        for field, value, shape in (
            ("stiffness", stiffness, (6,)),
            ("damping", damping, (6,)),
            ("rest_length", rest_length, ()),
        ):
            name = f"{label}.{field}"
            value = as_float_array(value, name, shape)
            value = require(value, value >= 0, f"{name} must be >= 0", value)
            setattr(self, field, jnp.asarray(value))
        self.rest_angles = jnp.asarray(
            as_float_array(rest_angles, f"{label}.rest_angles", (3,))
        )


def _deflection_scale(sq: Scalar, rest_length: Scalar) -> Scalar:
    """$1 - \\rho_0/|d|$ from $|d|^2$, guarded at $|d| = 0$ (where it is 1)."""
    ok = sq > 0
    inverse_length = jax.lax.rsqrt(jnp.where(ok, sq, 1.0))
    return 1.0 - jnp.where(ok, rest_length * inverse_length, 0.0)


def deflection(d: Vector3, rest_length: Scalar) -> Vector3:
    """Deflection of a link, $\\delta = (1 - \\rho_0/|d|)\\, d$, $d = r_i - r_j$.

    For $\\rho_0 > 0$ it is singular at $|d| = 0$ (the direction is lost): the value
    there is guarded (no NaN, also in gradients) and `simulate` stops with an error
    before a link collapses. For $\\rho_0 = 0$ it is simply $d$, smooth everywhere.
    """
    return _deflection_scale(jnp.sum(d * d), rest_length) * d


def _strain(dy: Vector6, rest_length: Scalar, rest_angles: Vector3) -> Vector6:
    """$(\\delta, \\Delta\\mathcal{A} - \\Delta\\mathcal{A}_0)$ of one connection
    from $\\Delta Y = Y_i - Y_j$, as one 6-vector: the deflection of the
    translational part $d$ and the angles' difference, each on its own three
    entries (split apart: the transpose of a split is a concatenation)."""
    d, angles = jnp.split(dy, 2)
    return jnp.concatenate(
        [_deflection_scale(jnp.sum(d * d), rest_length) * d, angles - rest_angles]
    )


def connection_potential(
    stiffness: Float[Array, " 6"],
    rest_length: Scalar,
    rest_angles: Vector3,
    yi: Vector6,
    yj: Vector6,
) -> Scalar:
    """$\\Pi_{ij} = \\tfrac12\\sum_k c^k \\delta_k^2
    + \\tfrac12\\sum_a c^a (\\Delta\\mathcal{A}_a - \\Delta\\mathcal{A}_{0,a})^2$
    of one connection (`jax.vmap` it for many)."""
    strain = _strain(yi - yj, rest_length, rest_angles)
    return 0.5 * jnp.sum(stiffness * strain * strain)


def connection_dissipation(
    damping: Float[Array, " 6"],
    rest_length: Scalar,
    yi: Vector6,
    yj: Vector6,
    vi: Vector6,
    vj: Vector6,
) -> Scalar:
    """$R_{ij} = \\tfrac12 \\dot\\delta^T D^\\delta \\dot\\delta
    + \\tfrac12 \\Delta\\dot{\\mathcal{A}}^T D^{\\mathcal A} \\Delta\\dot{\\mathcal{A}}$
    of one connection, with $\\dot\\delta = \\mathcal{G}(d)\\,\\dot d$ the deflection
    rate: the Jacobian $\\mathcal{G}$ of the deflection is applied by a
    forward-mode product (of the strain, whose angular part has Jacobian 1)."""
    rest_angles = jnp.zeros(3, yi.dtype)  # (constant: no part of the rate)
    _, rate = jax.jvp(
        lambda dy: _strain(dy, rest_length, rest_angles), (yi - yj,), (vi - vj,)
    )
    return 0.5 * jnp.sum(damping * rate * rate)


def _incidence(
    pairs: Sequence[tuple[int, int]], n_bodies: int
) -> tuple[Int[np.ndarray, "bodies width"], Float[np.ndarray, "bodies width"]]:
    """Static per-body lists of the connections at each body: `(index, sign)`
    arrays `(bodies, K)` (sign +1 where the body is the first end, -1 the second,
    0 padding), K the largest number of connections at one body."""
    rows: list[list[tuple[int, float]]] = [[] for _ in range(n_bodies)]
    for k, (i, j) in enumerate(pairs):
        rows[i].append((k, 1.0))
        rows[j].append((k, -1.0))
    width = max(1, max(len(r) for r in rows))
    index = np.zeros((n_bodies, width), dtype=np.int32)
    sign = np.zeros((n_bodies, width))
    for b, row in enumerate(rows):
        for slot, (k, s) in enumerate(row):
            index[b, slot], sign[b, slot] = k, s
    return index, sign


def _signed_sum(
    g: Sequence[Vector6],
    index: Int[np.ndarray, " width"],
    sign: Float[np.ndarray, " width"],
) -> Vector6:
    """$\\sum_s \\pm g_{k_s}$ over one body's connections (`g`: the connections'
    rows; `index`, `sign` from `_incidence`, a zero sign pads); zero for a body
    without one."""
    terms = [g[int(k)] if s > 0 else -g[int(k)] for k, s in zip(index, sign) if s]
    if not terms:
        return jnp.zeros_like(g[0])
    return functools.reduce(operator.add, terms)


# Gather the per-connection forces per body (dense padded lists, no scatter) while
# bodies x (largest degree) stays within this factor of bodies + 2 connections;
# beyond (a hub with many links) a segment sum keeps the cost linear.
_GATHER_OVERHEAD = 4
# Largest number of connections at one body for which the per-body sum is unrolled.
_UNROLL = 8
# Up to this many connections, each connection's ends are read from Y, and each
# body's sum is formed, from the rows of a split instead of by gathers. A gather's
# transpose is a scatter-add into a zeroed buffer, a split's a concatenation, so
# the vector field's vector-Jacobian product (the gradients' main cost) holds
# fewer operations, with the same values (`benchmarks/product_parts.py`;
# docs/performance.md). Beyond, gathers, as the program would grow with the
# connections.
_SPLIT_CONNECTIONS = 4


class MobileModel(AbstractElasticModel):
    """Appendix B: motion about the mobile unloaded state.

    $$\\Pi = \\sum_{(i,j)} \\Pi_{ij}, \\qquad R = \\sum_{(i,j)} R_{ij},$$

    one term per connection (see `connection_potential`, `connection_dissipation`).
    Connection parameters are stored stacked over the $P$ connections, so a `vmap`
    or a gradient over stiffness is one over a single array:

    - `model.pairs`: integer array `(P, 2)`,
    - `model.stiffness`, `model.damping`: `(P, 6)`,
    - `model.rest_length`: `(P,)`, `model.rest_angles`: `(P, 3)`.

    **Arguments:**

    - `bodies`: sequence of `RigidBody`, the object first ($m + 1$ bodies, $m \\ge 0$).
    - `connections`: sequence of `Connection` (may be empty for a single free body).
    - `gravity`: $g$ [m/s^2] along $-z$.
    - `convention`: `"zxz"` (default) or `"rpy"`.
    """

    bodies: RigidBody
    stiffness: Float[Array, "connections 6"]
    damping: Float[Array, "connections 6"]
    rest_length: Float[Array, " connections"]
    rest_angles: Float[Array, "connections 3"]
    gravity: Scalar
    convention: str = eqx.field(static=True)
    connectivity: tuple[tuple[int, int], ...] = eqx.field(static=True)

    def __init__(self, bodies, connections=(), gravity=9.81, convention="zxz"):
        get_rotation(convention)
        self.convention = convention
        self.bodies = stack_bodies(bodies)
        n = int(np.shape(self.bodies.mass)[0])
        connections = list(connections)
        for k, c in enumerate(connections):
            if not isinstance(c, Connection):
                raise ValueError(
                    f"MobileModel.connections[{k}] must be a Connection, got {c!r}"
                )
            for end in (c.i, c.j):
                if end >= n:
                    raise ValueError(
                        f"MobileModel.connections[{k}] = Connection({c.i}, {c.j}) "
                        f"refers to body {end}, but the model has {n} bodies "
                        f"(indices 0..{n - 1})"
                    )
        self.connectivity = tuple((c.i, c.j) for c in connections)

        def stacked(field, shape):
            if not connections:
                return jnp.zeros((0, *shape))
            return stack([getattr(c, field) for c in connections])

        self.stiffness = stacked("stiffness", (6,))
        self.damping = stacked("damping", (6,))
        self.rest_length = stacked("rest_length", ())
        self.rest_angles = stacked("rest_angles", (3,))
        self.gravity = check_gravity(gravity)

    @property
    def pairs(self) -> Pairs:
        """The connected pairs $(i, j)$, an integer array `(connections, 2)` (a
        constant of the model's structure)."""
        return np.array(self.connectivity, dtype=np.int32).reshape(-1, 2)

    @property
    def n_connections(self) -> int:
        return len(self.connectivity)

    def _ends(
        self, y: State
    ) -> tuple[Float[Array, "connections 6"], Float[Array, "connections 6"]]:
        """Both ends' rows of `y` for every connection, `(connections, 6)` each."""
        pairs = self.pairs
        if 0 < len(pairs) <= _SPLIT_CONNECTIONS:
            rows = jnp.split(y, y.shape[0])
            return (
                jnp.concatenate([rows[int(i)] for i in pairs[:, 0]]),
                jnp.concatenate([rows[int(j)] for j in pairs[:, 1]]),
            )
        return y[pairs[:, 0]], y[pairs[:, 1]]

    def _potential_of_ends(self, yi: State, yj: State) -> Scalar:
        """$\\Pi$ from both ends' coordinates `(connections, 6)` of every link."""
        per = jax.vmap(connection_potential)(
            self.stiffness, self.rest_length, self.rest_angles, yi, yj
        )
        return jnp.sum(per)

    def _dissipation_of_ends(
        self, yi: State, yj: State, vi: State, vj: State
    ) -> Scalar:
        """$R$ from both ends' coordinates and rates `(connections, 6)`."""
        per = jax.vmap(connection_dissipation)(
            self.damping, self.rest_length, yi, yj, vi, vj
        )
        return jnp.sum(per)

    def potential(self, y: State) -> Scalar:
        return self._potential_of_ends(*self._ends(y))

    def dissipation(self, y: State, ydot: State) -> Scalar:
        return self._dissipation_of_ends(*self._ends(y), *self._ends(ydot))

    def restoring_forces(self, y: State, ydot: State) -> tuple[State, State]:
        """$(\\partial\\Pi/\\partial Y, \\partial R/\\partial\\dot Y)$, each
        `(bodies, 6)`.

        Per connection, by autodiff of $\\Pi_{ij}$ and $R_{ij}$ with respect to the
        first end's coordinates (`vmap` over the connections); both depend on
        $Y_i - Y_j$ only, so the second end gets the opposite. The ends and the
        per-body sums come from the static connectivity: from the rows of a split
        for up to 4 connections, by gathers beyond (no scatter-add in the hot
        path).
        """
        n = self.n_bodies
        if not self.connectivity:
            zero = jnp.zeros_like(y)
            return zero, zero
        yi, yj = self._ends(y)
        vi, vj = self._ends(ydot)
        elastic = jax.grad(self._potential_of_ends)(yi, yj)
        damping = jax.grad(self._dissipation_of_ends, argnums=2)(yi, yj, vi, vj)
        index, sign = _incidence(self.connectivity, n)
        pairs = self.pairs

        def per_body(g: Float[Array, "connections 6"]) -> State:
            """The sum over each body's connections of +-`g` (+ at the first end)."""
            if len(pairs) <= _SPLIT_CONNECTIONS:
                rows = [row[0] for row in jnp.split(g, len(pairs))]
                return jnp.stack(
                    [_signed_sum(rows, i, s) for i, s in zip(index, sign, strict=True)]
                )
            if index.size > _GATHER_OVERHEAD * (n + 2 * len(pairs)):
                ends = np.concatenate([pairs[:, 0], pairs[:, 1]])
                return jax.ops.segment_sum(jnp.concatenate([g, -g]), ends, n)
            if index.shape[1] > _UNROLL:
                return jnp.sum(g[index] * sign[..., None], axis=1)
            terms = [g[index[:, s]] * sign[:, s, None] for s in range(index.shape[1])]
            return functools.reduce(operator.add, terms)

        return per_body(elastic), per_body(damping)

    def elastic_admissible(self, definiteness: bool = True) -> BoolScalar:
        """Stiffness, damping and rest lengths finite and >= 0, rest angles
        finite (no check needs a decomposition: `definiteness` changes nothing)."""
        np_ = xp(self.stiffness, self.damping, self.rest_length, self.rest_angles)

        def finite_nonnegative(x):
            return np_.all(np_.isfinite(x) & (x >= 0))

        return (
            finite_nonnegative(self.stiffness)
            & finite_nonnegative(self.damping)
            & finite_nonnegative(self.rest_length)
            & np_.all(np_.isfinite(self.rest_angles))
        )

    def elastic_refusal(self) -> str | None:
        """The first connection whose values `Connection` refuses, with its
        message."""
        for k, (i, j) in enumerate(self.connectivity):
            try:
                Connection(
                    i,
                    j,
                    self.stiffness[k],
                    self.damping[k],
                    self.rest_length[k],
                    self.rest_angles[k],
                )
            except ValueError as err:
                return f"connection {k}: {err}"
        return None

    def stiffness_matrix(
        self, y: Float[ArrayLike, "bodies 6"] | None = None
    ) -> DofMatrix:
        """$\\partial^2 \\Pi/\\partial Y^2$ at `y`, shape `(6(m+1), 6(m+1))` (it
        depends on the configuration: `y` is required)."""
        if y is None:
            raise ValueError(
                "MobileModel.stiffness_matrix needs a configuration y: the "
                "stiffness of Appendix B depends on it"
            )
        y = as_float_array(
            y, "MobileModel.stiffness_matrix.y", (self.n_bodies, 6), check_traced=False
        )
        return _potential_hessian(self, jnp.asarray(y))

    def connection_wrench(self, y: State) -> Float[Array, "connections 6"]:
        """Generalized elastic force of each connection on its first body $i$,
        $-\\partial \\Pi_{ij}/\\partial Y_i$, shape `(P, 6)`: three world-axis force
        components [N] and three generalized torques [N m]. The force on body $j$ is
        the opposite."""
        yi, yj = self._ends(y)
        grad_i = jax.vmap(jax.grad(connection_potential, argnums=3))(
            self.stiffness, self.rest_length, self.rest_angles, yi, yj
        )
        return -grad_i

    def link_lengths(self, y: State) -> Float[Array, " connections"]:
        """$|r_i - r_j|$ per connection, shape `(P,)`."""
        yi, yj = self._ends(y)
        return jnp.sqrt(jnp.sum((yi[:, :3] - yj[:, :3]) ** 2, axis=-1))

    def with_unloaded_state(self, y: Float[ArrayLike, "bodies 6"]) -> "MobileModel":
        """The same model with rest lengths and rest angles set so that `y` is
        unloaded ($\\rho_{ij0} = |r_i - r_j|$, $\\Delta\\mathcal{A}_{ij0} =
        \\mathcal{A}_i - \\mathcal{A}_j$)."""
        y = jnp.asarray(as_float_array(y, "y", (self.n_bodies, 6)))
        yi, yj = self._ends(y)
        lengths = self.link_lengths(y)
        if is_concrete(lengths) and np.any(np.asarray(lengths) == 0):
            k = int(np.argmin(np.asarray(lengths)))
            i, j = (int(v) for v in np.asarray(self.pairs[k]))
            raise ValueError(
                f"bodies {i} and {j} coincide in y, so connection {k} has no direction"
            )
        return eqx.tree_at(
            lambda m: (m.rest_length, m.rest_angles),
            self,
            (lengths, yi[:, 3:] - yj[:, 3:]),
        )


@eqx.filter_jit
def _potential_hessian(model: MobileModel, y: State) -> DofMatrix:
    """$\\partial^2 \\Pi/\\partial Y^2$ of the flattened $Y$, compiled (evaluated
    op by op, the Hessian would compile each of its many small operations)."""
    n = 6 * model.n_bodies
    return jax.hessian(lambda q: model.potential(q.reshape(y.shape)))(y.reshape(n))
