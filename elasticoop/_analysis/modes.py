"""Natural frequencies, damping ratios and mode shapes of a `LinearModel`."""

import equinox as eqx
import numpy as np
from jaxtyping import Float, Inexact

from .._custom_types import Validated
from .linear import LinearModel


class Modes(eqx.Module):
    """Modes of $M\\ddot q + C\\dot q + Kq = 0$ (see `modes`).

    **Fields:**

    - `frequencies`: undamped natural angular frequencies $\\omega_k$ [rad/s],
      ascending (rigid-body modes have $\\omega = 0$).
    - `damping_ratios`: modal damping ratios
      $\\zeta_k = \\phi_k^T C\\phi_k / (2\\omega_k)$ ($\\phi_k$ mass-normalized;
      exact for proportional damping, the usual estimate otherwise; `nan` for a
      rigid mode).
    - `shapes`: mass-normalized mode shapes $\\phi_k$ as columns, `(f, f)`.
    - `eigenvalues`: the exact complex eigenvalues $\\lambda$ of the state matrix
      $A$ (damped modes: $\\lambda = -\\zeta\\omega \\pm i\\omega\\sqrt{1-\\zeta^2}$),
      sorted by $|\\lambda|$.
    - `names`: names of the free coordinates (rows of `shapes`).
    """

    frequencies: Float[np.ndarray, " modes"]
    damping_ratios: Float[np.ndarray, " modes"]
    shapes: Float[np.ndarray, "modes modes"]
    eigenvalues: Inexact[np.ndarray, " states"]
    names: tuple[str, ...] = eqx.field(static=True)

    @property
    def frequencies_hz(self) -> Float[np.ndarray, " modes"]:
        return self.frequencies / (2 * np.pi)

    def table(self, count: int | None = None) -> str:
        """A text table: mode, frequency [Hz], damping ratio, dominant coordinate."""
        count = len(self.frequencies) if count is None else count
        lines = [
            f"{'mode':>4}  {'f [Hz]':>10}  {'omega [rad/s]':>13}  {'zeta':>8}  "
            "dominant coordinate",
        ]
        for k in range(min(count, len(self.frequencies))):
            shape = self.shapes[:, k]
            top = int(np.argmax(np.abs(shape)))
            zeta = self.damping_ratios[k]
            lines.append(
                f"{k + 1:>4}  {self.frequencies_hz[k]:>10.4f}  "
                f"{self.frequencies[k]:>13.4f}  "
                f"{'-' if np.isnan(zeta) else f'{zeta:.4f}':>8}  {self.names[top]}"
            )
        return "\n".join(lines)


def modes(linear: Validated[LinearModel], rigid_tol: float = 1e-9) -> Modes:
    """Solve the generalized eigenproblem $K\\phi = \\omega^2 M\\phi$ (SciPy's
    symmetric-definite `eigh`) and the eigenvalues of the state matrix.

    `rigid_tol`: eigenvalues $\\omega^2$ below `rigid_tol` times the largest are
    rigid-body modes ($\\omega = 0$).
    """
    import scipy.linalg  # here: loading a scenario imports this module, not SciPy

    if not isinstance(linear, LinearModel):
        raise ValueError(
            f"modes takes a LinearModel, got {type(linear).__name__}; linearize "
            f"the model about an equilibrium first: "
            f"modes(linearize(model, y_eq, prescribed))"
        )
    M, C, K = (np.asarray(x) for x in (linear.M, linear.C, linear.K))
    omega2, shapes = scipy.linalg.eigh(K, M)
    top = max(float(np.max(np.abs(omega2))), np.finfo(float).tiny)
    omega2 = np.where(np.abs(omega2) < rigid_tol * top, 0.0, omega2)
    if np.any(omega2 < 0):
        raise ValueError(
            "the stiffness is not positive semi-definite here (smallest "
            f"omega^2 = {omega2.min():.3e}): the configuration is an unstable "
            "equilibrium, so it has no oscillation modes"
        )
    omega = np.sqrt(omega2)
    modal_c = np.einsum("ik,ij,jk->k", shapes, C, shapes)
    with np.errstate(divide="ignore", invalid="ignore"):
        zeta = np.where(omega > 0, modal_c / (2 * omega), np.nan)
    A = np.asarray(linear.state_space().A)
    eig = np.linalg.eigvals(A)
    eig = eig[np.argsort(np.abs(eig), kind="stable")]
    return Modes(
        frequencies=omega,
        damping_ratios=zeta,
        shapes=shapes,
        eigenvalues=eig,
        names=linear.names,
    )
