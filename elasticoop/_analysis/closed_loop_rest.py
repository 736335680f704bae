"""The state at rest in the closed loop: every coordinate that is not held (the
object's AND the contact bodies') where the applied force law balances the
elastic and gravity forces.

`rest_state` holds the contact bodies at given poses and takes the applied forces
as numbers. In a simulation the contact bodies are free: they move under the
force law $F(t, Y, \\dot Y)$ (e.g. a `PoseTracking` controller, whose feedforward
is a number fixed by the experiment). A system whose parameters differ from the
ones that feedforward was computed for is at rest only where the controller's
forces at rest balance its own reactions, $Y^*$ solving
$$r(Y) = \\frac{\\partial\\Pi}{\\partial Y}(Y) - G - F(t_0, Y, 0) = 0$$
over the free coordinates. Its Jacobian is the closed-loop stiffness
$K(Y) - \\partial F/\\partial Y$ ($K + K_p$ on the grasps for `PoseTracking`),
non-singular where the force law holds the contact bodies.

Traceable (`jax.jit`, `jax.vmap`) and differentiable: the solution's derivatives
with respect to the model's and the force's parameters come from the implicit
function theorem (`optimistix.ImplicitAdjoint`),
$\\partial Y^*/\\partial p = -(\\partial r/\\partial Y)^{-1}\\,\\partial r/\\partial p$.
"""

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Float, Int

from .._custom_types import ArrayInput, State
from .._forces import check_force_shape, pad_to_bodies
from .._lagrange import elastic_forces
from .._models import AbstractElasticModel
from ._common import as_mask

ForceLaw = Callable[..., ArrayInput]
"""A force law $F(t, Y, \\dot Y)$ -> `(m, 6)` or `(bodies, 6)` (an
`AbstractForce`), or `None` for none."""

_Args = tuple[AbstractElasticModel, State, Int[Array, " free"], ForceLaw | None, Array]


def closed_loop_residual(
    model: AbstractElasticModel,
    y: ArrayInput,
    forces: ForceLaw | None = None,
    t0: ArrayInput = 0.0,
) -> State:
    """$\\partial\\Pi/\\partial Y - G - F(t_0, Y, 0)$, `(bodies, 6)`: the force
    imbalance of the configuration `y` at rest under the force law `forces`
    (zero at a closed-loop rest state, on its free coordinates)."""
    n = model.n_bodies
    y = jnp.asarray(y, jnp.float64)
    r = elastic_forces(model, y) - model.gravity_forces()
    if forces is None:
        return r
    F = jnp.asarray(
        forces(jnp.asarray(t0, jnp.float64), y, jnp.zeros_like(y)), jnp.float64
    )
    check_force_shape(F.shape, n)
    return r - pad_to_bodies(F, n)


def _imbalance(y_free: Float[Array, " free"], args: _Args) -> Float[Array, " free"]:
    model, y_guess, free, forces, t0 = args
    y = y_guess.reshape(-1).at[free].set(y_free).reshape(y_guess.shape)
    return closed_loop_residual(model, y, forces, t0).reshape(-1)[free]


def closed_loop_rest(
    model: AbstractElasticModel,
    y_guess: ArrayInput,
    forces: ForceLaw | None = None,
    t0: ArrayInput = 0.0,
    held: ArrayInput | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    max_steps: int = 256,
    throw: bool = True,
) -> State:
    """The configuration at rest in the closed loop: the free coordinates solving
    $\\partial\\Pi/\\partial Y = G + F(t_0, Y, 0)$, the held ones at their values
    in `y_guess`.

    Unlike `rest_state`, the applied forces are the force law evaluated at the
    solution (at rest, $\\dot Y = 0$, at time `t0`), and by default every
    coordinate is free: the contact bodies settle where the manipulators' forces
    balance their grasps' reactions. A force law's numbers (a `PoseTracking`
    feedforward, its gains and reference poses) are what they are: they do not
    change with the model's parameters. Levenberg-Marquardt (a trust-region
    Newton method) drives the force imbalance to zero from `y_guess`; its Jacobian
    is the closed-loop stiffness $K - \\partial F/\\partial Y$, which must be
    non-singular at the solution (a force law that holds the contact bodies, such
    as `PoseTracking` with positive gains; constant forces leave the whole system
    free to drift, with no isolated rest state).

    Traceable: the model, `y_guess`, the force law's arrays and `t0` may be traced
    (under `jit`, `vmap`, `jvp`, `grad`: derivatives by the implicit function
    theorem, see the module's docstring); `held` must be a concrete bool array.

    **Arguments:**

    - `model`: an `ImmobileModel` or `MobileModel`.
    - `y_guess`: `(bodies, 6)`: the start of the solver (e.g. the rest state of
      nominal parameters) and the held coordinates' values.
    - `forces`: the force law $F(t, Y, \\dot Y)$ (an `AbstractForce`, e.g.
      `PoseTracking`), `None`: none.
    - `t0`: the time [s] at which the force law is evaluated (the start).
    - `held`: bool `(bodies, 6)`, true for a held coordinate; default: none.
    - `rtol`, `atol`, `max_steps`: the solver's tolerances and most iterations.
    - `throw`: raise (`equinox.error_if`, also under `jit`) when the solver does
      not converge; `False` returns NaN instead (a failed sample of a study).

    **Returns:** $Y$ at rest, `(bodies, 6)`.
    """
    n = model.n_bodies
    mask = as_mask(held, n, "held")
    free = np.flatnonzero(~mask.reshape(-1))
    if free.size == 0:
        raise ValueError("held fixes every coordinate: nothing to solve for")
    y_guess = jnp.asarray(y_guess, dtype=jnp.float64)
    if y_guess.shape != (n, 6):
        raise ValueError(f"y_guess must have shape ({n}, 6), got {y_guess.shape}")
    import optimistix as optx  # imported when a solve is traced

    args = (model, y_guess, jnp.asarray(free), forces, jnp.asarray(t0, jnp.float64))
    solution: optx.Solution = optx.root_find(
        _imbalance,
        optx.LevenbergMarquardt(rtol=rtol, atol=atol),
        y_guess.reshape(-1)[free],
        args=args,
        max_steps=max_steps,
        adjoint=optx.ImplicitAdjoint(),
        throw=False,
    )
    converged = solution.result == optx.RESULTS.successful
    y = y_guess.reshape(-1).at[free].set(solution.value).reshape(n, 6)
    if throw:
        return eqx.error_if(
            y,
            ~converged,
            f"closed_loop_rest: the solver did not converge in {max_steps} steps; "
            f"start closer to the rest state, or check that the force law holds "
            f"the free coordinates (a non-singular closed-loop stiffness)",
        )
    return jnp.where(converged, y, jnp.nan)


def closed_loop_stiffness(
    model: AbstractElasticModel,
    y: ArrayInput,
    forces: ForceLaw | None = None,
    t0: ArrayInput = 0.0,
) -> Float[Array, "dof dof"]:
    """$\\partial r/\\partial Y = K(Y) - \\partial F(t_0, Y, 0)/\\partial Y$,
    `(6 (m + 1), 6 (m + 1))`: the Jacobian of `closed_loop_residual` (its
    restriction to the free coordinates must be non-singular at a rest state)."""
    y = jnp.asarray(y, jnp.float64)

    def flat(v):
        return closed_loop_residual(model, v.reshape(y.shape), forces, t0).reshape(-1)

    return jax.jacfwd(flat)(y.reshape(-1))


__all__ = [
    "closed_loop_residual",
    "closed_loop_rest",
    "closed_loop_stiffness",
]
