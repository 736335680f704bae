"""What every elastic-system model provides: bodies, gravity, $\\Pi$ and $R$."""

import abc

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .._body import RigidBody, kinetic_energy
from .._custom_types import BoolScalar, DofMatrix, Scalar, State
from .._rotations import AbstractRotation, get_rotation
from .._validation import is_concrete, xp

# Eigenvalues below this fraction of the largest count as zero in `rank K`.
RANK_RTOL = 1e-9


class AbstractElasticModel(eqx.Module):
    """An elastic system of $m + 1$ rigid bodies (body 0 the object, 1..m the
    contact bodies) with generalized coordinates
    $Y_i = (x, y, z, a_1, a_2, a_3)$ stacked body-major as an array `(bodies, 6)`.

    A concrete model defines the potential energy $\\Pi(Y)$ and the Rayleigh function
    $R(Y, \\dot Y)$; the kinetic energy $T = \\sum_i T_i$ and the gravity potential
    $\\sum_i m_i g z_i$ are common to all.
    """

    bodies: eqx.AbstractVar[RigidBody]
    gravity: eqx.AbstractVar[Scalar]
    convention: eqx.AbstractVar[str]

    @abc.abstractmethod
    def elastic_admissible(self, definiteness: bool = True) -> BoolScalar:
        """Whether the elastic parameters pass the checks of construction (part
        of `admissible`), by `xp` so that it works traced or not; without
        `definiteness`, the checks that need no matrix decomposition."""

    def admissible(self, definiteness: bool = True) -> BoolScalar:
        """Whether the parameters pass the checks of construction (bodies,
        $g \\ge 0$, the elastic parameters), traced or not: for a model whose
        values were changed afterwards (`eqx.tree_at`, a Monte Carlo draw), which
        no constructor has checked (the ranges and finiteness; not the rank of
        an immobile model's K). Evaluated by NumPy when the values are
        concrete. `definiteness=False` leaves out the checks that need an
        eigenvalue decomposition (an immobile model's K and D semidefinite), for
        a program that must not call LAPACK (`simulate`'s, under a trace)."""
        # NumPy leaves where concrete: JAX operators on concrete arrays would still
        # be staged into a surrounding `jit`
        model = jax.tree.map(np.asarray, self) if is_concrete(self) else self
        np_ = xp(model.gravity)
        return (
            model.bodies.admissible()
            & np_.isfinite(model.gravity)
            & (model.gravity >= 0)
            & model.elastic_admissible(definiteness)
        )

    def refusal(self) -> str | None:
        """For a concrete model, the message of the first check of construction
        its values fail (a body's, gravity's, then `elastic_refusal`), `None` if
        they pass: what `admissible` finds false, said as the constructor says it,
        for a model whose values were changed afterwards."""
        model = jax.tree.map(np.asarray, self)
        for i, (mass, inertia) in enumerate(
            zip(model.bodies.mass, model.bodies.inertia, strict=True)
        ):
            try:
                RigidBody(mass, inertia)
            except ValueError as err:
                return f"body {i}: {err}"
        gravity = float(model.gravity)
        if not (np.isfinite(gravity) and gravity >= 0):
            return f"gravity must be finite and >= 0 [m/s^2], got {gravity!r}"
        return model.elastic_refusal()

    @abc.abstractmethod
    def elastic_refusal(self) -> str | None:
        """`refusal` of the elastic parameters (concrete, NumPy leaves)."""

    @abc.abstractmethod
    def potential(self, y: State) -> Scalar:
        """Elastic potential energy $\\Pi(Y)$ [J]."""

    @abc.abstractmethod
    def dissipation(self, y: State, ydot: State) -> Scalar:
        """Rayleigh dissipation function $R(Y, \\dot Y)$ [W]; the dissipated power
        is $\\dot Y \\cdot \\partial R/\\partial \\dot Y = 2R$."""

    @property
    def rotation(self) -> AbstractRotation:
        return get_rotation(self.convention)

    @property
    def n_bodies(self) -> int:
        return int(np.shape(self.bodies.mass)[-1])

    @property
    def n_manipulators(self) -> int:
        """$m$, the number of contact bodies (all bodies but the object)."""
        return self.n_bodies - 1

    def kinetic_energy(self, y: State, ydot: State) -> Scalar:
        """$T = \\sum_i T_i(Y_i, \\dot Y_i)$ [J]."""
        per_body = kinetic_energy(
            self.bodies,
            self.rotation,
            tuple(y[..., k] for k in range(6)),
            tuple(ydot[..., k] for k in range(6)),
        )
        return jnp.sum(per_body)

    def gravity_potential(self, y: State) -> Scalar:
        """$\\sum_i m_i g z_i$ [J] (gravity along $-z$)."""
        return self.gravity * jnp.sum(self.bodies.mass * y[:, 2])

    def gravity_forces(self) -> State:
        """$G_i = (0, 0, -m_i g, 0, 0, 0)$, shape `(bodies, 6)`."""
        zero = jnp.zeros_like(self.bodies.mass)
        weight = -self.gravity * self.bodies.mass
        return jnp.stack([zero, zero, weight, zero, zero, zero], axis=-1)

    @abc.abstractmethod
    def restoring_forces(self, y: State, ydot: State) -> tuple[State, State]:
        """$(\\partial\\Pi/\\partial Y, \\partial R/\\partial\\dot Y)$, each
        `(bodies, 6)`: autodiff of `potential` and `dissipation`
        (`autodiff_restoring_forces`), or a cheaper route to the same derivatives."""

    def total_energy(self, y: State, ydot: State) -> Scalar:
        """$E = T + \\Pi + \\sum_i m_i g z_i$ [J]."""
        return (
            self.kinetic_energy(y, ydot) + self.potential(y) + self.gravity_potential(y)
        )

    @abc.abstractmethod
    def stiffness_matrix(
        self, y: Float[ArrayLike, "bodies 6"] | None = None
    ) -> DofMatrix:
        """$\\partial^2 \\Pi/\\partial Y^2$ at `y`, shape `(6(m+1), 6(m+1))`."""

    def stiffness_rank(self, y: Float[ArrayLike, "bodies 6"] | None = None) -> int:
        """rank K of the stiffness at configuration `y` (eigenvalues below
        `RANK_RTOL` times the largest count as zero)."""
        if y is not None:
            y = jnp.asarray(y, dtype=jnp.float64)
        return numerical_rank(self.stiffness_matrix(y))

    def n_prescribed(self, y: Float[ArrayLike, "bodies 6"] | None = None) -> int:
        """$6m + 6 - \\operatorname{rank} K$: coordinates to prescribe to fix the
        system's static position at configuration `y`."""
        return 6 * self.n_bodies - self.stiffness_rank(y)


def autodiff_restoring_forces(
    model: AbstractElasticModel, y: State, ydot: State
) -> tuple[State, State]:
    """$(\\partial\\Pi/\\partial Y, \\partial R/\\partial\\dot Y)$ by autodiff of
    the model's `potential` and `dissipation`."""
    elastic = jax.grad(model.potential)(y)
    damping = jax.grad(model.dissipation, argnums=1)(y, ydot)
    return elastic, damping


def numerical_rank(k: Float[ArrayLike, "n n"]) -> int:
    """Rank of a symmetric matrix: eigenvalues below `RANK_RTOL` times the largest
    (in magnitude) count as zero."""
    k = np.asarray(k)
    if k.size == 0 or not np.any(k):
        return 0
    top = np.max(np.abs(np.linalg.eigvalsh(k)))
    return int(np.linalg.matrix_rank(k, tol=RANK_RTOL * top, hermitian=True))
