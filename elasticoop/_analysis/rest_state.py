"""The state at rest: a static equilibrium as a traceable, differentiable function
of the model's parameters.

`static_equilibrium` answers a question about one model and checks its answer in
Python (uniqueness, convergence). `rest_state` is the same equation written as a
JAX function, so that it can sit inside a fit or a study: it runs under `jax.jit`
and `jax.vmap`, and its derivatives with respect to the model's parameters
(`jax.jvp`, `jax.jacfwd`, `jax.grad`) come from the implicit function theorem
(`optimistix.ImplicitAdjoint`): at the solution $Y^*(p)$ of
$r(Y_f, p) = [\\partial\\Pi/\\partial Y - G - F]_f = 0$,
$$\\frac{\\partial Y_f^*}{\\partial p} = -K_{ff}^{-1}\\,
\\frac{\\partial r}{\\partial p},$$
one linear solve with the restricted stiffness $K_{ff}$ instead of a derivative
through the solver's iterations.
"""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool

from .._custom_types import ArrayInput, State
from .._forces import check_force_shape, pad_to_bodies
from .._models import AbstractElasticModel
from .._validation import as_float_array
from ._common import as_mask
from .equilibrium import _energy, _full, _imbalance


def contact_bodies_held(n_bodies: int) -> Bool[np.ndarray, "bodies 6"]:
    """The default held coordinates of a rest state: every coordinate of the
    contact bodies (bodies 1..m), at their commanded poses; the object is free."""
    mask = np.zeros((n_bodies, 6), dtype=bool)
    mask[1:] = True
    return mask


def rest_state(
    model: AbstractElasticModel,
    y_guess: ArrayInput,
    forces: ArrayInput | None = None,
    held: ArrayInput | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    max_steps: int = 256,
    throw: bool = True,
) -> State:
    """The configuration at rest: the free coordinates solving
    $\\partial\\Pi/\\partial Y = G + F$, the held ones at their values in
    `y_guess`.

    The applied forces $F$ are numbers (the commanded forces at rest at the start,
    $F(t_0, Y, 0)$, as the experimenter applied them): they do not change with the
    model's parameters. The free coordinates are found as `static_equilibrium`
    finds them (the same residual and energy functions): BFGS descends the
    potential energy $V = \\Pi + \\sum_i m_i g z_i - F\\cdot Y$ from `y_guess`,
    then Levenberg-Marquardt drives the force imbalance to zero. Only the last
    stage is differentiated, by the implicit function theorem (see the module's
    docstring); the first only supplies its start.

    Traceable: the model and `y_guess` and `forces` may be traced values (under
    `jit`, `vmap`, `jvp`, `grad`); `held` must be a concrete bool array.

    **Arguments:**

    - `model`: an `ImmobileModel` or `MobileModel`.
    - `y_guess`: `(bodies, 6)`: the held coordinates' values (the commanded poses)
      and the start of the free ones (e.g. the rest state of nominal parameters).
    - `forces`: constant generalized forces as numbers, `(m, 6)` on the contact
      bodies or `(bodies, 6)`; `None`: none.
    - `held`: bool `(bodies, 6)`, true for a held coordinate; default: every
      coordinate of the contact bodies (`contact_bodies_held`), as
      `[initial] from = "equilibrium"` holds them without a `[prescribed]` table.
      The free coordinates' stiffness must be non-singular at the rest state
      (see `static_equilibrium`).
    - `rtol`, `atol`, `max_steps`: the solvers' tolerances and most iterations.
    - `throw`: raise (`equinox.error_if`, also under `jit`) when the solver does
      not converge; `False` returns NaN instead, so that a caller (a fit's trial
      point) can treat it as a failed evaluation.

    **Returns:** $Y$ at rest, `(bodies, 6)`.
    """
    n = model.n_bodies
    mask = contact_bodies_held(n) if held is None else as_mask(held, n, "held")
    free = np.flatnonzero(~mask.reshape(-1))
    if free.size == 0:
        raise ValueError("held fixes every coordinate: nothing to solve for")
    # (shapes always, finiteness where concrete: the values may be traced)
    y_guess = jnp.asarray(
        as_float_array(y_guess, "rest_state.y_guess", (n, 6), check_traced=False)
    )
    if forces is None:
        F = jnp.zeros((n, 6))
    else:
        F = jnp.asarray(
            as_float_array(forces, "rest_state.forces", (None, 6), check_traced=False)
        )
        check_force_shape(F.shape, n)
        F = pad_to_bodies(F, n)
    import optimistix as optx  # imported when a solve is traced

    args = (model, y_guess, jnp.asarray(free), F)
    descent: optx.Solution = optx.minimise(
        _energy,
        optx.BFGS(rtol=rtol, atol=atol),
        y_guess.reshape(-1)[free],
        args=args,
        max_steps=max_steps,
        throw=False,
    )
    # the descent only gives the start: its derivative is not wanted
    start = jax.lax.stop_gradient(descent.value)
    solution: optx.Solution = optx.root_find(
        _imbalance,
        optx.LevenbergMarquardt(rtol=rtol, atol=atol),
        start,
        args=args,
        max_steps=max_steps,
        adjoint=optx.ImplicitAdjoint(),
        throw=False,
    )
    converged = solution.result == optx.RESULTS.successful
    y = _full(solution.value, args)
    if throw:
        return _checked(y, converged, max_steps)
    return jnp.where(converged, y, jnp.nan)


def _checked(y: State, converged: Array | bool, max_steps: int) -> State:
    return eqx.error_if(
        y,
        ~converged,
        f"rest_state: the static equilibrium solver did not converge in "
        f"{max_steps} steps; start closer to the rest state, hold more "
        f"coordinates, or raise max_steps",
    )


__all__ = ["contact_bodies_held", "rest_state"]
