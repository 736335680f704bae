"""Appendix A: the immobile unloaded state, a constant stiffness matrix K."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import ArrayLike, Float

from .._body import RigidBody, stack_bodies
from .._custom_types import ArrayInput, BoolScalar, DofMatrix, Scalar, State
from .._rotations import get_rotation
from .._validation import as_float_array, is_concrete, require, xp
from .base import AbstractElasticModel, autodiff_restoring_forces, numerical_rank

# Relative tolerances for "K is symmetric" and "K is positive semidefinite".
SYMMETRY_RTOL = 1e-10
PSD_RTOL = 1e-9


def check_symmetric_psd(matrix, name: str):
    """Validate a symmetric positive semidefinite matrix (works traced or not):
    $\\max|M - M^T| \\le$ `SYMMETRY_RTOL` $\\max|M|$ and smallest eigenvalue of
    $(M + M^T)/2$ $\\ge$ -`PSD_RTOL` $\\max|M|$. A concrete matrix that fails is
    reported with the offending value and the bound."""
    scale, asym, low = _asymmetry_and_lowest_eigenvalue(matrix)
    symmetric = asym <= SYMMETRY_RTOL * scale
    if is_concrete(symmetric) and not bool(symmetric):
        raise ValueError(
            f"{name} must be symmetric, but its largest entry of |{name} - {name}^T| "
            f"is {float(asym):.6g} (at most {SYMMETRY_RTOL:g} max|{name}| = "
            f"{SYMMETRY_RTOL * float(scale):.3g} allowed)"
        )
    matrix = require(matrix, symmetric, f"{name} must be symmetric")
    semidefinite = low >= -PSD_RTOL * scale
    if is_concrete(semidefinite) and not bool(semidefinite):
        raise ValueError(
            f"{name} must be positive semidefinite, but its smallest eigenvalue is "
            f"{float(low):.6g} (at least -{PSD_RTOL:g} max|{name}| = "
            f"{-PSD_RTOL * float(scale):.3g} allowed)"
        )
    return require(matrix, semidefinite, f"{name} must be positive semidefinite")


def _asymmetry_and_lowest_eigenvalue(matrix):
    """$(\\max|M|, \\max|M - M^T|$, the smallest eigenvalue of $(M + M^T)/2)$ (the
    largest entry floored at 1e-300)."""
    np_ = xp(matrix)
    scale = np_.maximum(np_.max(np_.abs(matrix)), 1e-300)
    asym = np_.max(np_.abs(matrix - matrix.T))
    eig = np_.linalg.eigvalsh(0.5 * (matrix + matrix.T))
    low = np_.min(eig) if eig.size else np_.zeros(())
    return scale, asym, low


def symmetric_psd(matrix) -> BoolScalar:
    """Whether `matrix` passes `check_symmetric_psd`, traced or not (by NumPy
    when concrete)."""
    np_ = xp(matrix)
    finite = np_.all(np_.isfinite(matrix))
    # (eigenvalues of a finite stand-in: NumPy's fail on NaN)
    scale, asym, low = _asymmetry_and_lowest_eigenvalue(np_.where(finite, matrix, 0.0))
    return finite & (asym <= SYMMETRY_RTOL * scale) & (low >= -PSD_RTOL * scale)


def check_stiffness(K, n_bodies: int):
    """K must be symmetric positive semidefinite of rank at most $6m$."""
    K = check_symmetric_psd(K, "K")
    if is_concrete(K):
        rank = numerical_rank(K)
        if rank > 6 * (n_bodies - 1):
            raise ValueError(
                f"rank K must be <= 6m = {6 * (n_bodies - 1)} for m = {n_bodies - 1} "
                f"manipulators (a free system has a rigid-motion null space), "
                f"got rank K = {rank}"
            )
    return K


def check_gravity(gravity: ArrayInput) -> Scalar:
    gravity = as_float_array(gravity, "gravity", ())
    gravity = require(gravity, gravity >= 0, "gravity must be >= 0 [m/s^2]", gravity)
    return jnp.asarray(gravity)


class ImmobileModel(AbstractElasticModel):
    """Appendix A: motion about the immobile unloaded state $Y_0$.

    $$\\Pi = \\tfrac12 (Y - Y_0)^T K (Y - Y_0), \\qquad
      R = \\tfrac12 \\dot Y^T D \\dot Y,$$

    with $K = K^T \\ge 0$, $\\operatorname{rank} K \\le 6m$ and $D = D^T \\ge 0$, both
    $(6m+6)\\times(6m+6)$ over the body-major stacked coordinates. The state is the
    absolute configuration $Y$ (so $y = Y - Y_0$); $T$ is evaluated at the absolute
    angles.

    **Arguments:**

    - `bodies`: sequence of `RigidBody`, the object first.
    - `K`, `D`: stiffness [N/m, N m/rad, ...] and damping matrices.
    - `y0`: unloaded configuration $Y_0$, shape `(bodies, 6)`. With ZXZ angles it must
      not sit at $\\theta = 0$ (gimbal lock).
    - `gravity`: $g$ [m/s^2], acting along $-z$.
    - `convention`: `"zxz"` (default, the appendix's) or `"rpy"`.
    """

    bodies: RigidBody
    K: DofMatrix
    D: DofMatrix
    y0: State
    gravity: Scalar
    convention: str = eqx.field(static=True)

    def __init__(self, bodies, K, D, y0, gravity=9.81, convention="zxz"):
        get_rotation(convention)
        self.convention = convention
        self.bodies = stack_bodies(bodies)
        n = int(np.shape(self.bodies.mass)[0])
        size = 6 * n
        K = as_float_array(K, "ImmobileModel.K", (size, size))
        D = as_float_array(D, "ImmobileModel.D", (size, size))
        self.K = jnp.asarray(check_stiffness(K, n))
        self.D = jnp.asarray(check_symmetric_psd(D, "D"))
        self.y0 = jnp.asarray(as_float_array(y0, "ImmobileModel.y0", (n, 6)))
        self.gravity = check_gravity(gravity)

    def potential(self, y: State) -> Scalar:
        dy = (y - self.y0).reshape(-1)
        return 0.5 * dy @ (self.K @ dy)

    def dissipation(self, y: State, ydot: State) -> Scalar:
        v = ydot.reshape(-1)
        return 0.5 * v @ (self.D @ v)

    def restoring_forces(self, y: State, ydot: State) -> tuple[State, State]:
        return autodiff_restoring_forces(self, y, ydot)

    def elastic_admissible(self, definiteness: bool = True) -> BoolScalar:
        """The symmetric parts of K and D positive semidefinite (with
        `definiteness`), K, D and Y_0 finite. (Only the symmetric parts enter
        $\\Pi$ and $R$: a draw that perturbs the entries one by one is not
        symmetric, but is admissible when its symmetric parts are stable.)"""
        np_ = xp(self.K, self.D, self.y0)
        if not definiteness:
            return (
                np_.all(np_.isfinite(self.K))
                & np_.all(np_.isfinite(self.D))
                & np_.all(np_.isfinite(self.y0))
            )

        def symmetric_part(M):
            return 0.5 * (M + M.T)

        return (
            symmetric_psd(symmetric_part(self.K))
            & symmetric_psd(symmetric_part(self.D))
            & np_.all(np_.isfinite(self.y0))
        )

    def elastic_refusal(self) -> str | None:
        """The first of K, D (their symmetric parts: the skew parts enter neither
        $\\Pi$ nor $R$) and $Y_0$ that the constructor's checks refuse."""
        try:
            for name in ("K", "D"):
                matrix = np.asarray(getattr(self, name))
                as_float_array(matrix, f"ImmobileModel.{name}", matrix.shape)
                check_symmetric_psd(0.5 * (matrix + matrix.T), name)
            as_float_array(self.y0, "ImmobileModel.y0", self.y0.shape)
        except ValueError as err:
            return str(err)
        return None

    def stiffness_matrix(
        self, y: Float[ArrayLike, "bodies 6"] | None = None
    ) -> DofMatrix:
        """K (constant for this model; `y` may be omitted)."""
        return self.K
