"""How long a step of an explicit Runge-Kutta method may be and stay stable.

A step of length $h$ maps a perturbation along an eigenvector of the linearized
motion, eigenvalue $\\lambda$, by the method's stability polynomial
$R(z) = 1 + \\sum_{k=1}^{s} \\gamma_k z^k$ at $z = h\\lambda$, with
$\\gamma_k = b^T A^{k-1}\\mathbb{1}$ from the Butcher tableau ($A$ strictly lower
triangular). The error control of an adaptive solver sees only what the solution
excites: at rest in an equilibrium nothing is, and the steps grow until $|R|$ is
far above 1 for the fastest modes. The solution stays at rest, but its derivatives
(which follow the perturbations) grow by $|R|$ at every step: `jax.grad` of a run
that starts at rest gave $10^{11}$ where the finite difference gives 0.77.

`stability_radius` is the radius $r$ of the largest half-disc
$\\{|z| \\le r, \\operatorname{Re} z \\le 0\\}$ on which
$|R(z)| \\le 1 + 10^{-3}$. A step no longer than $r / \\rho$, with $\\rho$ a bound
of $|\\lambda|$ over the linearized motion, then grows no mode, damped or not, by
more than $10^{-3}$: a factor of $e$ over a thousand such steps at rest, for a mode
without damping. (The tolerance admits the methods whose region leaves the
imaginary axis near 0: $|R(iy)| = 1 + O(y^4)$ for the second-order ones,
$1 + O(y^6)$ for Tsit5 and Dopri5, whose radii it takes from 0.05 to 0.3 and from
0.6 and 1.0 to 1.3; Dopri8's is 3.8.)
"""

import functools

import diffrax
import numpy as np

# |R(z)| allowed on the half-disc: growth of at most 1e-3 a step
_GROWTH = 1e-3
# the radii tried, and the points on each half-circle
_RADII = np.arange(1, 2001) * 0.005
_ANGLES = np.linspace(np.pi / 2, 3 * np.pi / 2, 721)


def stability_radius(solver: diffrax.AbstractSolver) -> float:
    """The stability radius $r$ of `solver` (the module's docstring); `inf` for a
    solver that is not an explicit Runge-Kutta method with a Butcher tableau (an
    implicit one is stable on the whole half-plane)."""
    tableau = getattr(solver, "tableau", None)
    if not (
        isinstance(solver, diffrax.AbstractERK)
        and isinstance(tableau, diffrax.ButcherTableau)
    ):
        return float("inf")
    b = tuple(float(x) for x in tableau.b_sol)
    lower = tuple(tuple(float(x) for x in row) for row in tableau.a_lower)
    return _radius(b, lower)


@functools.cache
def _radius(b: tuple[float, ...], lower: tuple[tuple[float, ...], ...]) -> float:
    s = len(b)
    A = np.zeros((s, s))
    for i, row in enumerate(lower):
        A[i + 1, : i + 1] = row
    # gamma_k = b^T A^(k-1) 1, k = 1 ... s (A is nilpotent: the sum ends at s)
    gamma, v = [1.0], np.ones(s)
    for _ in range(s):
        gamma.append(float(np.dot(b, v)))
        v = A @ v
    coefficients = np.asarray(gamma[::-1])  # highest power first, for np.polyval
    stable = 0.0
    for r in _RADII:
        if np.max(np.abs(np.polyval(coefficients, r * np.exp(1j * _ANGLES)))) > (
            1.0 + _GROWTH
        ):
            break
        stable = float(r)
    return stable
