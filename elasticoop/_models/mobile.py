"""Appendix B: the mobile unloaded state, pairwise springs with rest length."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._body import RigidBody, stack_bodies
from .._custom_types import Pairs, Scalar, State, Vector3
from .._rotations import get_rotation
from .._validation import as_float_array, is_concrete, require
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
    stiffness: jnp.ndarray
    damping: jnp.ndarray
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


def deflection(d: Vector3, rest_length: Scalar) -> Vector3:
    """Deflection of a link, $\\delta = (1 - \\rho_0/|d|)\\, d$, $d = r_i - r_j$.

    For $\\rho_0 > 0$ it is singular at $|d| = 0$ (the direction is lost): the value
    there is guarded (no NaN, also in gradients) and `simulate` stops with an error
    before a link collapses. For $\\rho_0 = 0$ it is simply $d$, smooth everywhere.
    """
    sq = d @ d
    ok = sq > 0
    length = jnp.sqrt(jnp.where(ok, sq, 1.0))
    return d - jnp.where(ok, rest_length / length, 0.0) * d


def connection_potential(stiffness, rest_length, rest_angles, yi, yj) -> Scalar:
    """$\\Pi_{ij} = \\tfrac12\\sum_k c^k \\delta_k^2
    + \\tfrac12\\sum_a c^a (\\Delta\\mathcal{A}_a - \\Delta\\mathcal{A}_{0,a})^2$."""
    delta = deflection(yi[:3] - yj[:3], rest_length)
    d_angles = yi[3:] - yj[3:] - rest_angles
    return 0.5 * (stiffness[:3] @ delta**2 + stiffness[3:] @ d_angles**2)


def connection_dissipation(damping, rest_length, yi, yj, vi, vj) -> Scalar:
    """$R_{ij} = \\tfrac12 \\dot\\delta^T D^\\delta \\dot\\delta
    + \\tfrac12 \\Delta\\dot{\\mathcal{A}}^T D^{\\mathcal A} \\Delta\\dot{\\mathcal{A}}$
    with $\\dot\\delta = \\mathcal{G}(d)\\,\\dot d$ the deflection rate: the Jacobian
    $\\mathcal{G}$ of the deflection is applied by a forward-mode product."""
    _, delta_rate = jax.jvp(
        lambda d: deflection(d, rest_length), (yi[:3] - yj[:3],), (vi[:3] - vj[:3],)
    )
    angle_rate = vi[3:] - vj[3:]
    return 0.5 * (damping[:3] @ delta_rate**2 + damping[3:] @ angle_rate**2)


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
    pairs: Pairs
    stiffness: jnp.ndarray
    damping: jnp.ndarray
    rest_length: jnp.ndarray
    rest_angles: jnp.ndarray
    gravity: Scalar
    convention: str = eqx.field(static=True)

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
        self.pairs = jnp.asarray(
            np.array([(c.i, c.j) for c in connections], dtype=np.int32).reshape(-1, 2)
        )

        def stacked(field, shape):
            if not connections:
                return jnp.zeros((0, *shape))
            return jnp.stack([getattr(c, field) for c in connections])

        self.stiffness = stacked("stiffness", (6,))
        self.damping = stacked("damping", (6,))
        self.rest_length = stacked("rest_length", ())
        self.rest_angles = stacked("rest_angles", (3,))
        self.gravity = check_gravity(gravity)

    @property
    def n_connections(self) -> int:
        return int(np.shape(self.pairs)[0])

    def _ends(self, y: State):
        return y[self.pairs[:, 0]], y[self.pairs[:, 1]]

    def potential(self, y: State) -> Scalar:
        yi, yj = self._ends(y)
        per = jax.vmap(connection_potential)(
            self.stiffness, self.rest_length, self.rest_angles, yi, yj
        )
        return jnp.sum(per)

    def dissipation(self, y: State, ydot: State) -> Scalar:
        yi, yj = self._ends(y)
        vi, vj = self._ends(ydot)
        per = jax.vmap(connection_dissipation)(
            self.damping, self.rest_length, yi, yj, vi, vj
        )
        return jnp.sum(per)

    def connection_wrench(self, y: State) -> jnp.ndarray:
        """Generalized elastic force of each connection on its first body $i$,
        $-\\partial \\Pi_{ij}/\\partial Y_i$, shape `(P, 6)`: three world-axis force
        components [N] and three generalized torques [N m]. The force on body $j$ is
        the opposite."""
        yi, yj = self._ends(y)
        grad_i = jax.vmap(jax.grad(connection_potential, argnums=3))(
            self.stiffness, self.rest_length, self.rest_angles, yi, yj
        )
        return -grad_i

    def link_lengths(self, y: State) -> jnp.ndarray:
        """$|r_i - r_j|$ per connection, shape `(P,)`."""
        yi, yj = self._ends(y)
        return jnp.sqrt(jnp.sum((yi[:, :3] - yj[:, :3]) ** 2, axis=-1))

    def with_unloaded_state(self, y: State) -> "MobileModel":
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
