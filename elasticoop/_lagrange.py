"""Lagrange's equations with dissipation, by autodiff of $T$, $\\Pi$ and $R$.

$$W(Y)\\ddot Y + w(Y, \\dot Y) = G + F, \\qquad W = \\partial^2 T/\\partial \\dot Y^2,$$
$$w = \\frac{\\partial^2 T}{\\partial \\dot Y\\,\\partial Y}\\dot Y
      - \\frac{\\partial T}{\\partial Y}
      + \\frac{\\partial R}{\\partial \\dot Y} + \\frac{\\partial \\Pi}{\\partial Y}.$$

The derivation, and the corrections to the printed appendix that the tests rely
on, are in `docs/model.md` (sections 4 and 6). Nothing here is derived by hand;
the structure of the problem is used to keep the derivatives cheap:

- $T = \\sum_i T_i(Y_i, \\dot Y_i)$ is evaluated for all bodies at once, coordinate by
  coordinate (six arrays of shape `(bodies,)`), so under `jit`/`vmap` it is one
  elementwise computation that XLA fuses into a few loops.
- $W$ is block diagonal over bodies, and in the structure of $T_i$ (mass centre,
  principal axes, $\\omega = L_\\omega\\dot{\\mathcal{A}}$) each block is
  $W_i = \\operatorname{diag}(m_i 1_3, L_\\omega^T I_i L_\\omega)$ (`_mass_blocks`):
  the free accelerations are $b_{lin}/m_i$ and
  $L_\\omega^{-1} I_i^{-1} L_\\omega^{-T} b_{rot}$, with the closed-form inverse of
  $L_\\omega$. `mass_matrix` forms $W$ by autodiff instead (column $k$ of every
  block from one forward-mode product of the momentum
  $p = \\partial T/\\partial\\dot Y$ along rate $k$ of every body), the independent
  route the tests compare the blocks with.
- With prescribed coordinates, the 3x3 blocks that hold one are solved by a
  closed-form $LDL^T$ factorisation (no pivoting: the blocks are positive definite
  away from gimbal lock).
- The velocity terms of the dynamics are taken in the same structure
  (`_structured_velocity_terms`: $L_\\omega^T$ times the gyroscopic part of
  Euler's equations, with $\\dot L_\\omega\\dot{\\mathcal{A}}$ one forward-mode
  product of the angular-velocity map). `velocity_terms` takes them from $T$
  alone instead: one Jacobian-vector product of $p$ along $\\dot Y$ minus
  $\\partial T/\\partial Y$, no Hessian formed; the tests compare the two.
- $\\partial\\Pi/\\partial Y$ and $\\partial R/\\partial\\dot Y$ come from the model's
  `restoring_forces` (per connection and gathered per body for `MobileModel`).
"""

import functools
import inspect
from collections.abc import Callable, Iterable
from typing import Any, TypeVar, cast

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float

from ._body import kinetic_energy
from ._compat import outside_transformations
from ._custom_types import (
    BodyCoordinate,
    BodyCoordinates,
    Mask,
    MassBlocks,
    Scalar,
    State,
    StateLike,
)
from ._mass_blocks import FactoredMassBlocks
from ._models import AbstractElasticModel
from ._validation import as_float_array, is_concrete

_COORDINATES = range(6)
# |sin theta| (ZXZ) or |cos pitch| (RPY) below which W is singular to working
# precision: `accelerations` refuses such a state
_SINGULAR = float(np.finfo(np.float64).eps)
_BLOCKS = ((0, 1, 2), (3, 4, 5))  # translations, Euler angles

_Term = TypeVar("_Term", bound=Callable[..., Any])
# The entries `W[i, k]` of all blocks $W_i$, each `(bodies,)` (or a structural 0.0).
_Blocks = dict[tuple[int, int], BodyCoordinate | float]


def _coordinates(x: State) -> BodyCoordinates:
    """`(bodies, 6)` -> six arrays `(bodies,)`, coordinate by coordinate (one
    split: its transpose in a gradient is one concatenation, where six slices'
    are six pads added up)."""
    return tuple(c[:, 0] for c in jnp.split(x, 6, axis=1))


def _mass_blocks(model: AbstractElasticModel, q: BodyCoordinates) -> FactoredMassBlocks:
    """The blocks $W_i$ at the coordinates `q` (`_coordinates` of $Y$), factored."""
    inertia = model.bodies.inertia
    return FactoredMassBlocks(
        model.bodies.mass,
        (inertia[:, 0], inertia[:, 1], inertia[:, 2]),
        model.rotation.angular_velocity_rows(q[3:6]),
    )


def _replace(xs: BodyCoordinates, k: int, value: BodyCoordinate) -> BodyCoordinates:
    return xs[:k] + (value,) + xs[k + 1 :]


def _kinetic_energy(
    model: AbstractElasticModel, q: BodyCoordinates, v: BodyCoordinates
) -> Scalar:
    """$T = \\sum_i T_i$ from coordinate tuples."""
    return jnp.sum(kinetic_energy(model.bodies, model.rotation, q, v))


def _momentum(
    model: AbstractElasticModel, q: BodyCoordinates, v: BodyCoordinates
) -> BodyCoordinates:
    """$p = \\partial T/\\partial\\dot Y$, six arrays `(bodies,)`."""
    return jax.grad(_kinetic_energy, argnums=2)(model, q, v)


def _mass_matrix_columns(
    model: AbstractElasticModel,
    q: BodyCoordinates,
    v: BodyCoordinates,
    columns: Iterable[int],
) -> _Blocks:
    """$W_{ik}$ for `k` in `columns`: column $k$ of all blocks $W_i$ at once by one
    forward-mode product of $p$ (linear in $\\dot Y$) along rate $k$ of every
    body. Returns `{(i, k): (bodies,)}` for all rows `i`."""
    out = {}
    ones = jnp.ones_like(v[0])
    for k in columns:
        _, column = jax.jvp(
            lambda vk, k=k: _momentum(model, q, _replace(v, k, vk)), (v[k],), (ones,)
        )
        for i in _COORDINATES:
            out[i, k] = column[i]
    return out


def _velocity_terms(
    model: AbstractElasticModel, q: BodyCoordinates, v: BodyCoordinates
) -> BodyCoordinates:
    """$(\\partial^2 T/\\partial\\dot Y\\partial Y)\\dot Y - \\partial T/\\partial Y$:
    one Jacobian-vector product of the momentum along $\\dot Y$."""
    _, momentum_rate = jax.jvp(lambda x: _momentum(model, x, v), (q,), (v,))
    dT_dq = jax.grad(_kinetic_energy, argnums=1)(model, q, v)
    return tuple(a - b for a, b in zip(momentum_rate, dT_dq))


def _structured_velocity_terms(
    model: AbstractElasticModel,
    W: FactoredMassBlocks,
    q: BodyCoordinates,
    v: BodyCoordinates,
) -> BodyCoordinates:
    """The velocity terms in the structure of $T_i$ (what `_velocity_terms` gives,
    with fewer operations; `tests/test_kinematics.py` compares the two).

    The translational rows vanish ($T_i$ is $\\tfrac12 m_i|\\dot r_i|^2$ there). With
    $\\omega = L_\\omega(\\mathcal{A})\\dot{\\mathcal{A}}$ the body-frame angular
    velocity, Lagrange's equations of $\\tfrac12\\omega^T I\\omega$ in the angles
    are $L_\\omega^T$ times Euler's equations, so the rotational rows are

    $$w_{rot} = L_\\omega^T\\left(I\\,\\dot L_\\omega\\dot{\\mathcal{A}}
        + \\omega\\times I\\omega\\right),$$

    where $\\dot L_\\omega\\dot{\\mathcal{A}}$, the part of $\\dot\\omega$ without
    $\\ddot{\\mathcal{A}}$, is one forward-mode product of the angular-velocity map
    along $\\dot{\\mathcal{A}}$ (docs/model.md, section 4.1).
    """
    rates = v[3:6]
    omega, omega_rate = jax.jvp(
        lambda a: model.rotation.angular_velocity_components(a, rates),
        (q[3:6],),
        (rates,),
    )
    inertia = W.inertia
    spin = tuple(inertia[k] * omega[k] for k in range(3))  # I omega
    body = [
        inertia[k] * omega_rate[k]
        + omega[(k + 1) % 3] * spin[(k + 2) % 3]
        - omega[(k + 2) % 3] * spin[(k + 1) % 3]
        for k in range(3)
    ]
    zero = jnp.zeros_like(v[0])
    return (zero, zero, zero, *W.rotational_transpose(tuple(body)))


def _ldl_solve3(
    W: _Blocks, rows: tuple[int, int, int], b: BodyCoordinates
) -> BodyCoordinates:
    """Solve the symmetric positive definite 3x3 system $W x = b$ (entries
    `W[rows[r], rows[c]]`, lower triangle used) by closed-form $LDL^T$."""
    i, j, k = rows
    d1 = W[i, i]
    r1 = 1.0 / d1
    l21 = W[j, i] * r1
    l31 = W[k, i] * r1
    d2 = W[j, j] - l21 * l21 * d1
    r2 = 1.0 / d2
    l32 = (W[k, j] - l31 * l21 * d1) * r2
    r3 = 1.0 / (W[k, k] - l31 * l31 * d1 - l32 * l32 * d2)
    z1 = b[0]
    z2 = b[1] - l21 * z1
    z3 = b[2] - l31 * z1 - l32 * z2
    x3 = z3 * r3
    x2 = z2 * r2 - l32 * x3
    x1 = z1 * r1 - l21 * x2 - l31 * x3
    return x1, x2, x3


def _compiled(term: _Term, solves: bool = False) -> _Term:
    """`term(model, *arrays)` as one compiled program per model structure and shape.

    Called outside `jit` (an analysis, a notebook cell), a term would otherwise run
    op by op, compiling each operation on its first use; inside a trace the call is
    inlined. The arrays, each `(bodies, 6)`, are checked and converted to float64
    first (an error names the function's argument; traced ones are checked for
    shape only), so that a nested list is data, not a static argument of the
    program. Called outside any transformation, a term that `solves` with $W$
    refuses a $Y$ at gimbal lock, where $W$ is singular.
    """
    jitted = eqx.filter_jit(term)
    names = [f"{term.__name__}.{p}" for p in inspect.signature(term).parameters][1:]

    @functools.wraps(term)
    def compiled(model: AbstractElasticModel, *arrays: Any) -> Any:
        shape = (model.n_bodies, 6)
        checked = [
            as_float_array(a, name, shape, check_traced=False)
            for name, a in zip(names, arrays, strict=False)
        ]
        if solves and outside_transformations() and is_concrete(model, checked):
            # W singular to working precision (a simulation stops well before,
            # at its `gimbal_tol`)
            model.rotation.check_regular(checked[0][:, 3:], _SINGULAR, names[0])
        return jitted(model, *(jnp.asarray(a) for a in checked))

    return cast(_Term, compiled)


@_compiled
def mass_matrix(model: AbstractElasticModel, y: StateLike) -> MassBlocks:
    """The diagonal blocks $W_i(Y_i)$ of the mass matrix, shape `(bodies, 6, 6)`."""
    y = jnp.asarray(y)
    q = _coordinates(y)
    W = _mass_matrix_columns(model, q, _coordinates(jnp.zeros_like(y)), _COORDINATES)
    return jnp.stack(
        [jnp.stack([W[i, k] for k in _COORDINATES], -1) for i in _COORDINATES], -2
    )


@_compiled
def velocity_terms(model: AbstractElasticModel, y: StateLike, ydot: StateLike) -> State:
    """$\\dot W_i \\dot Y_i - \\partial T_i/\\partial Y_i$ per body, shape
    `(bodies, 6)` (the Coriolis and centrifugal terms of $w$)."""
    y, ydot = jnp.asarray(y), jnp.asarray(ydot)
    c = _velocity_terms(model, _coordinates(y), _coordinates(ydot))
    return jnp.stack(c, -1)


@_compiled
def elastic_forces(model: AbstractElasticModel, y: StateLike) -> State:
    """$\\partial \\Pi/\\partial Y$, shape `(bodies, 6)` (includes the
    $\\partial\\pi_a/\\partial Y$ term of Appendix B)."""
    return jax.grad(model.potential)(y)


@_compiled
def damping_forces(model: AbstractElasticModel, y: StateLike, ydot: StateLike) -> State:
    """$\\partial R/\\partial \\dot Y$, shape `(bodies, 6)`."""
    y = jnp.asarray(y)
    return jax.grad(model.dissipation, argnums=1)(y, ydot)


def _balance(
    model: AbstractElasticModel, y: State, ydot: State, applied: State
) -> tuple[FactoredMassBlocks, BodyCoordinates, State]:
    """The one assembly of $W\\ddot Y = G + F - w$: every use of the equations of
    motion (free, prescribed and inverse dynamics) starts here.

    **Returns:** `(W, b, damping)`: the blocks $W_i$ (`FactoredMassBlocks`), the
    right-hand side $b = G + F - w$ as six arrays `(bodies,)`, and
    $\\partial R/\\partial\\dot Y$ `(bodies, 6)`.
    """
    q, v = _coordinates(y), _coordinates(ydot)
    elastic, damping = model.restoring_forces(y, ydot)
    rhs = model.gravity_forces() + applied - elastic - damping
    W = _mass_blocks(model, q)
    c = _structured_velocity_terms(model, W, q, v)
    b = tuple(r - c_k for r, c_k in zip(_coordinates(rhs), c, strict=True))
    return W, b, damping


def _entries(W: FactoredMassBlocks) -> _Blocks:
    """The entries `W[i, k]` within each 3x3 block (arrays or structural `0.0`)."""
    return {(i, k): W.entry(i, k) for block in _BLOCKS for i in block for k in block}


@functools.partial(_compiled, solves=True)
def accelerations(
    model: AbstractElasticModel, y: StateLike, ydot: StateLike, applied: StateLike
) -> tuple[State, State]:
    """Solve $W\\ddot Y = G + F - w$ per body ($\\ddot r_i = b_{lin}/m_i$,
    $\\ddot{\\mathcal{A}}_i = L_\\omega^{-1} I_i^{-1} L_\\omega^{-T} b_{rot}$).

    **Arguments:** the model, $Y$, $\\dot Y$ and the applied generalized forces $F$
    (all `(bodies, 6)`).

    **Returns:** `(yddot, damping)`, the accelerations and
    $\\partial R/\\partial\\dot Y$
    (whose product with $\\dot Y$ is the dissipated power $2R$).
    """
    y, ydot, applied = jnp.asarray(y), jnp.asarray(ydot), jnp.asarray(applied)
    W, b, damping = _balance(model, y, ydot, applied)
    return jnp.stack(W.solve(b), -1), damping


def constrained_accelerations(
    model: AbstractElasticModel,
    y: StateLike,
    ydot: StateLike,
    applied: StateLike,
    mask: Mask,
    yddot_prescribed: StateLike,
) -> tuple[State, State, State]:
    """Accelerations and reactions with the coordinates in `mask` prescribed.

    With $f$ the free and $p$ the prescribed coordinates of each body, the free rows
    of $W\\ddot Y + w = G + F$ are solved for $\\ddot Y_f$ given $\\ddot Y_p$,

    $$W_{ff}\\ddot Y_f = (G + F - w)_f - W_{fp}\\ddot Y_p,$$

    and the prescribed rows give the reactions, the generalized forces the drive
    must add to realise the motion: $Q_p = [W\\ddot Y + w - G - F]_p$ ($Q_f = 0$).
    Each 3x3 block with a prescribed coordinate is solved as the symmetric positive
    definite system $\\operatorname{diag}(W_{ff}, I)$ by a closed-form $LDL^T$; a
    block with none is solved as in `accelerations`, so with nothing prescribed
    this is exactly `accelerations`.

    **Arguments:** as `accelerations`, plus `mask`, a concrete bool array
    `(bodies, 6)` (true: prescribed), and `yddot_prescribed` `(bodies, 6)` (only
    its prescribed entries are used).

    **Returns:** `(yddot, damping, reaction)`, each `(bodies, 6)`, where `damping`
    is $\\partial R/\\partial\\dot Y$.
    """
    mask = np.asarray(mask, dtype=bool)
    y, ydot, applied = jnp.asarray(y), jnp.asarray(ydot), jnp.asarray(applied)
    yddot_prescribed = jnp.asarray(yddot_prescribed)
    blocks, b, damping = _balance(model, y, ydot, applied)
    W = _entries(blocks)
    a = _coordinates(yddot_prescribed)
    # Only coordinates prescribed for some body enter the elimination (a Python-level
    # choice on the concrete mask: a block with nothing prescribed is solved as in
    # the free dynamics).
    driven = {k: mask[:, k] for k in _COORDINATES if mask[:, k].any()}
    free = blocks.solve(b)
    yddot: list[BodyCoordinate] = []
    p: np.ndarray | bool
    for block in _BLOCKS:
        if not any(k in driven for k in block):
            yddot += [free[k] for k in block]
            continue
        S = dict(W)
        r = []
        for i in block:
            ri = b[i]
            for k, p in driven.items():
                if k in block:
                    ri = ri - jnp.where(p, W[i, k] * a[k], 0.0)
            r.append(jnp.where(driven[i], a[i], ri) if i in driven else ri)
        for i in block:
            for k in block:
                p = driven.get(i, False) | driven.get(k, False)
                if np.any(p):
                    S[i, k] = jnp.where(p, float(i == k), W[i, k])
        yddot += _ldl_solve3(S, block, tuple(r))
    reaction = [
        jnp.where(
            driven[i], sum(W[i, k] * yddot[k] for k in _BLOCKS[i // 3]) - b[i], 0.0
        )
        if i in driven
        else jnp.zeros_like(b[i])
        for i in _COORDINATES
    ]
    return jnp.stack(yddot, -1), damping, jnp.stack(reaction, -1)


@_compiled
def inverse_dynamics(
    model: AbstractElasticModel, y: StateLike, ydot: StateLike, yddot: StateLike
) -> State:
    """Generalized forces that realise a motion: $F = W\\ddot Y + w - G$,
    shape `(bodies, 6)`."""
    y, ydot, yddot = jnp.asarray(y), jnp.asarray(ydot), jnp.asarray(yddot)
    blocks, b, _ = _balance(model, y, ydot, jnp.zeros_like(y))
    W = _entries(blocks)
    a = _coordinates(yddot)
    return jnp.stack(
        [sum(W[i, k] * a[k] for k in _BLOCKS[i // 3]) - b[i] for i in _COORDINATES],
        -1,
    )


# how many products the power iteration of `linear_rate_bound` takes, and the
# margin it adds
_POWER_STEPS = 64
_RATE_MARGIN = 1.1


def linear_rate_bound(model: AbstractElasticModel, y: State) -> Scalar:
    """An estimate $\\rho$ from above of $|\\lambda|$ over the eigenvalues of the
    motion linearized about $Y$ at rest, $(\\lambda^2 W + \\lambda D + K) x = 0$,
    with $K = \\partial^2\\Pi/\\partial Y^2$, $D = \\partial^2 R/\\partial\\dot Y^2$
    and the mass matrix $W$. For $x^H W x = 1$, $\\lambda^2 + d\\lambda + k = 0$
    with $d = x^H D x \\in [0, a]$ and $|k| = |x^H K x| \\le b$, $a$ and $b$ the
    largest eigenvalues of $W^{-1}D$ and $W^{-1}K$ in magnitude. A pair of complex
    roots has $|\\lambda| = \\sqrt{k}$, a real one at most $d$ where $k \\ge 0$, so
    for a stiffness that does not soften

    $$\\rho = 1.1\\,\\max\\left(\\sqrt{b},\\; a\\right).$$

    $a$ and $b$ come from the power iteration, 64 products $v \\mapsto W^{-1}Kv$ and
    $v \\mapsto W^{-1}Dv$ in a loop, each a forward-mode derivative of the model's
    `restoring_forces` in $(Y, \\dot Y)$ at $\\dot Y = 0$: no matrix is formed and no
    LAPACK routine called (it runs inside any batch), and the program holds one
    copy of the forces, which keeps its compilation short. The margin of 10 %
    covers what the iteration leaves, and the softening of links under
    compression. `simulate` bounds its steps with it (`_integrate.stability`)."""
    zero = jnp.zeros_like(y)
    W = _mass_blocks(model, _coordinates(y))

    def forces(q: State, u: State) -> State:
        elastic, damping = model.restoring_forces(q, u)
        return elastic + damping

    def product(dq: State, du: State) -> State:  # W^-1 (K dq + D du)
        _, df = jax.jvp(forces, (y, zero), (dq, du))
        return jnp.stack(W.solve(_coordinates(df)), -1)

    def power_step(
        _: Array, carry: tuple[Float[Array, "2 bodies 6"], Float[Array, " 2"]]
    ) -> tuple[Float[Array, "2 bodies 6"], Float[Array, " 2"]]:
        v, _ = carry  # v[0] for W^-1 K, v[1] for W^-1 D
        w = jax.vmap(product)(jnp.stack([v[0], zero]), jnp.stack([zero, v[1]]))
        v_size = jnp.sqrt(jnp.sum(v * v, axis=(1, 2)))
        w_size = jnp.sqrt(jnp.sum(w * w, axis=(1, 2)))
        ratio = jnp.where(v_size > 0, w_size / jnp.where(v_size > 0, v_size, 1.0), 0.0)
        scale = jnp.max(jnp.abs(w), axis=(1, 2), keepdims=True)
        return w / jnp.maximum(scale, jnp.finfo(y.dtype).tiny), ratio

    start = 1.0 + 0.5 * jnp.sin(1.7 * jnp.arange(y.size, dtype=y.dtype))
    v = jnp.stack([start.reshape(y.shape)] * 2)
    # |mu| = |A v|/|v| after v = A^64 start (normalised on the way)
    _, (b, a) = jax.lax.fori_loop(
        0, _POWER_STEPS + 1, power_step, (v, jnp.zeros(2, y.dtype))
    )
    return _RATE_MARGIN * jnp.maximum(jnp.sqrt(b), a)
