"""The blocks of the mass matrix in the structure of the kinetic energy.

With $T_i = \\tfrac12 m_i|\\dot r_i|^2 + \\tfrac12\\omega_i^T I_i\\omega_i$
(principal axes, $I_i = \\operatorname{diag}(A_i, B_i, C_i)$) and
$\\omega_i = L_\\omega(\\mathcal{A}_i)\\dot{\\mathcal{A}}_i$ linear in the angle
rates, the Hessian of $T_i$ in the rates is

$$W_i = \\operatorname{diag}\\left(m_i 1_3,\\; L_\\omega^T I_i L_\\omega\\right),$$

so $W_i^{-1}$ is $m_i^{-1}$ on the translations and $L_\\omega^{-1} I_i^{-1}
L_\\omega^{-T}$ on the angles, with the closed-form 3x3 inverse of $L_\\omega$ (its
cofactors over its determinant, which vanishes only at gimbal lock). The
translational and rotational parts are evaluated from the same $m_i$, $I_i$ and
$L_\\omega$ that `kinetic_energy` uses; `tests/test_kinematics.py` checks the blocks
against the autodiff Hessian of $T$ (`elasticoop.mass_matrix`).

The entries of $L_\\omega$ come as arrays or as structural Python floats `0.0` and
`1.0` (`AbstractRotation.angular_velocity_rows`); the arithmetic below skips them,
so that the compiled program holds only the products that are not structurally zero.
"""

import functools
import operator
from typing import NamedTuple, cast

from ._custom_types import BodyCoordinate, BodyCoordinates
from ._rotations.base import AngularVelocityRows

# An entry: an array `(bodies,)`, or a structural 0.0 or 1.0.
_Entry = BodyCoordinate | float


def _is(x: _Entry, value: float) -> bool:
    return isinstance(x, float) and x == value


def _times(a: _Entry, b: _Entry) -> _Entry:
    if _is(a, 0.0) or _is(b, 0.0):
        return 0.0
    if _is(a, 1.0):
        return b
    if _is(b, 1.0):
        return a
    return a * b


def _sum(*terms: _Entry) -> _Entry:
    kept = [t for t in terms if not _is(t, 0.0)]
    return functools.reduce(operator.add, kept) if kept else 0.0


def _cofactors(L: AngularVelocityRows) -> tuple[tuple[_Entry, ...], ...]:
    """The cofactor matrix $C$ of a 3x3 matrix $L$: $L^{-1} = C^T/\\det L$."""

    def minor(r: int, c: int) -> _Entry:
        top, bottom = (x for x in range(3) if x != r)
        left, right = (x for x in range(3) if x != c)
        a, b = L[top][left], L[top][right]
        d, e = L[bottom][left], L[bottom][right]
        return _sum(_times(a, e), -_times(b, d))  # (-0.0 is still a structural zero)

    return tuple(
        tuple(minor(r, c) if (r + c) % 2 == 0 else -minor(r, c) for c in range(3))
        for r in range(3)
    )


class FactoredMassBlocks(NamedTuple):
    """$W_i = \\operatorname{diag}(m_i 1_3, L_\\omega^T I_i L_\\omega)$ for all bodies
    at once: `mass` $m_i$ `(bodies,)`, `inertia` $(A_i, B_i, C_i)$ as three arrays
    `(bodies,)` and `rows` the entries of $L_\\omega(\\mathcal{A}_i)$."""

    mass: BodyCoordinate
    inertia: BodyCoordinates
    rows: AngularVelocityRows

    def entry(self, i: int, k: int) -> _Entry:
        """$W[i, k]$ of every body (`(bodies,)`, or a structural `0.0`)."""
        if i < 3 or k < 3:
            return self.mass if i == k else 0.0
        L = self.rows
        return _sum(
            *(
                _times(self.inertia[r], _times(L[r][i - 3], L[r][k - 3]))
                for r in range(3)
            )
        )

    def rotational_transpose(self, g: BodyCoordinates) -> list[BodyCoordinate]:
        """$L_\\omega^T g$ for a body-frame $g$ given as three arrays `(bodies,)`
        (body-frame moments as generalized forces on the angles)."""
        L = self.rows
        out = [_sum(*(_times(L[r][c], g[r]) for r in range(3))) for c in range(3)]
        # (never a structural 0.0: every column of an invertible L has an entry)
        return cast(list[BodyCoordinate], out)

    def solve(self, b: BodyCoordinates) -> list[BodyCoordinate]:
        """$W^{-1} b$ for $b$ as six arrays `(bodies,)`: $b_{lin}/m$ and
        $L_\\omega^{-1} I^{-1} L_\\omega^{-T} b_{rot}$ (cofactors $C$ of $L_\\omega$:
        $L_\\omega^{-T} b = C b/\\det$, $L_\\omega^{-1} e = C^T e/\\det$)."""
        L = self.rows
        C = _cofactors(L)
        det = _sum(*(_times(L[0][c], C[0][c]) for c in range(3)))
        scale = 1.0 / (det * det)
        rot = b[3:6]
        # det * L^-T b, then divided by the principal moments
        e = [
            _sum(*(_times(C[r][c], rot[c]) for c in range(3))) / self.inertia[r]
            for r in range(3)
        ]
        angles = [
            _sum(*(_times(C[r][c], e[r]) for r in range(3))) * scale for c in range(3)
        ]
        # (never a structural 0.0: every column of an invertible L has an entry)
        return [x / self.mass for x in b[0:3]] + cast(list[BodyCoordinate], angles)
