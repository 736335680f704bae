"""Linearization about an equilibrium: $M\\ddot q + C\\dot q + Kq = Bu$."""

from collections.abc import Iterable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, ArrayLike, Float, Int

from .._custom_types import ArrayInput, State
from .._lagrange import mass_matrix
from .._models import AbstractElasticModel
from .._naming import body_names as body_names_of, dof_names
from .._validation import as_float_array
from ._common import as_mask


class StateSpace(eqx.Module):
    """$\\dot x = Ax + Bu$, $z = Cx + Du$ with $x = (q, \\dot q)$, $u$ the
    generalized forces on all $6m + 6$ coordinates and $z = q$."""

    A: Float[Array, "states states"]
    B: Float[Array, "states inputs"]
    C: Float[Array, "outputs states"]
    D: Float[Array, "outputs inputs"]


class LinearModel(eqx.Module):
    """Small motions $q = Y_f - Y_{f,eq}$ of the free coordinates about an
    equilibrium, with the prescribed coordinates held fixed:

    $$M\\ddot q + C\\dot q + Kq = Bu,$$

    $M = W_{ff}(Y_{eq})$, $C = [\\partial^2 R/\\partial\\dot Y^2]_{ff}$,
    $K = [\\partial^2 \\Pi/\\partial Y^2]_{ff}$ (gravity is linear in $Y$ and adds
    no stiffness; the velocity terms of $w$ are quadratic in $\\dot Y$ and drop
    out), all by autodiff at $(Y_{eq}, 0)$. $u$ is the stacked generalized force on
    all $6m + 6$ coordinates and $B$ selects its free rows.

    **Fields:** `M`, `C`, `K` `(f, f)`; `B` `(f, 6m + 6)`; `y_eq`; `free` (indices of
    the free coordinates in the stacked $Y$); `names` (their names).
    """

    M: Float[Array, "free free"]
    C: Float[Array, "free free"]
    K: Float[Array, "free free"]
    B: Float[Array, "free dofs"]
    y_eq: State
    free_indices: tuple[int, ...] = eqx.field(static=True)
    names: tuple[str, ...] = eqx.field(static=True)

    @property
    def free(self) -> Int[np.ndarray, " free"]:
        """Indices of the free coordinates in the stacked $Y$."""
        return np.array(self.free_indices, dtype=int)

    def state_space(self) -> StateSpace:
        """The first-order form for control design."""
        f = self.M.shape[0]
        inv_m = jnp.linalg.inv(self.M)
        zero, eye = jnp.zeros((f, f)), jnp.eye(f)
        A = jnp.block([[zero, eye], [-inv_m @ self.K, -inv_m @ self.C]])
        B = jnp.concatenate([jnp.zeros_like(self.B), inv_m @ self.B])
        C = jnp.concatenate([eye, zero], axis=1)
        D = jnp.zeros((f, self.B.shape[1]))
        return StateSpace(A, B, C, D)

    def to_full(
        self, q: Float[ArrayLike, "*batch free"]
    ) -> Float[Array, "*batch bodies 6"]:
        """Free-coordinate vector(s) `(..., f)` to configurations `(..., bodies, 6)`
        about `y_eq`."""
        q = jnp.asarray(q)
        flat = jnp.broadcast_to(self.y_eq.reshape(-1), (*q.shape[:-1], self.B.shape[1]))
        return flat.at[..., self.free].add(q).reshape(*q.shape[:-1], -1, 6)


def linearize(
    model: AbstractElasticModel,
    y_eq: ArrayInput,
    prescribed: ArrayInput | None = None,
    body_names: Iterable[str] | None = None,
) -> LinearModel:
    """The linear model about `y_eq` with the `prescribed` coordinates fixed.

    `y_eq` should be a static equilibrium (see `static_equilibrium`); the linear
    model describes small motions about it. For a configuration that is not in
    equilibrium the constant force imbalance is not part of the model.

    **Arguments:** the model, the configuration `(bodies, 6)`, and the bool
    `(bodies, 6)` mask of prescribed coordinates (`None`: all free); `body_names`
    name the coordinates in `LinearModel.names`, `<body>.<coordinate>` (default
    bodies `object`, `contact1`, ...: `object.x`, ..., `contact1.psi`).
    """
    n = model.n_bodies
    y_eq = jnp.asarray(as_float_array(y_eq, "y_eq", (n, 6)))
    mask = as_mask(prescribed, n)
    free = np.flatnonzero(~mask.reshape(-1))
    if free.size == 0:
        raise ValueError("prescribed fixes every coordinate: no motion to linearize")
    M, K, D = _second_derivatives(model, y_eq)
    index = np.ix_(free, free)
    B = jnp.eye(6 * n)[free]
    names = dof_names(body_names_of(body_names, n), model.convention)
    return LinearModel(
        M=0.5 * (M + M.T)[index],
        C=0.5 * (D + D.T)[index],
        K=0.5 * (K + K.T)[index],
        B=B,
        y_eq=y_eq,
        free_indices=tuple(int(i) for i in free),
        names=tuple(names[i] for i in free),
    )


@eqx.filter_jit  # one program, not op by op, when called outside `jit`
def _second_derivatives(
    model: AbstractElasticModel, y_eq: State
) -> tuple[Float[Array, "n n"], Float[Array, "n n"], Float[Array, "n n"]]:
    """The mass matrix, $\\partial^2\\Pi/\\partial Y^2$ and
    $\\partial^2 R/\\partial\\dot Y^2$ at $(Y_{eq}, 0)$, each `(6 bodies, 6 bodies)`."""
    M = jax.scipy.linalg.block_diag(*mass_matrix(model, y_eq))
    K = model.stiffness_matrix(y_eq)
    D = jax.hessian(lambda v: model.dissipation(y_eq, v.reshape(y_eq.shape)))(
        jnp.zeros(y_eq.size)
    )
    return M, K, D
