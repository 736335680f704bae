"""Static equilibrium with some coordinates prescribed."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from .._compile_options import fast_compile_jit
from .._custom_types import ArrayInput, DofMatrix, Scalar, State
from .._lagrange import elastic_forces
from .._models import AbstractElasticModel
from .._models.base import numerical_rank
from .._options import SimulationOptions
from .._traces import stored_program
from .._validation import as_float_array, is_concrete
from ._common import as_mask, constant_forces

# `args` of the solvers: the model, the guess (holding the prescribed values), the
# indices of the free coordinates in the stacked $Y$, and the applied forces.
_Args = tuple[AbstractElasticModel, State, Int[Array, " free"], State]


class Equilibrium(eqx.Module):
    """A static equilibrium (see `static_equilibrium`).

    **Fields:**

    - `y`: the equilibrium configuration, `(bodies, 6)`.
    - `reaction`: generalized forces on the prescribed coordinates that hold them,
      $Q_p = [\\partial\\Pi/\\partial Y - G - F]_p$, `(bodies, 6)` (zero on the free
      coordinates).
    - `residual`: largest $|\\partial\\Pi/\\partial Y - G - F|$ over the free
      coordinates [N, N m].
    - `stiffness`: $K_{ff}$, the stiffness restricted to the free coordinates there.
    - `mask`: the prescribed coordinates.
    - `steps`: iterations of the solver.
    """

    y: State
    reaction: State
    residual: Scalar
    stiffness: Float[Array, "free free"]
    mask_tuple: tuple[tuple[bool, ...], ...] = eqx.field(static=True)
    steps: int = eqx.field(static=True)

    @property
    def mask(self) -> Bool[np.ndarray, "bodies 6"]:
        """The prescribed coordinates, bool `(bodies, 6)`."""
        return np.array(self.mask_tuple, dtype=bool)

    @property
    def stable(self) -> bool:
        """True when $K_{ff}$ is positive definite (an isolated minimum of the
        potential energy)."""
        return bool(np.linalg.eigvalsh(np.asarray(self.stiffness)).min() > 0)


def _restricted_stiffness(
    model: AbstractElasticModel, y: State, free: Int[np.ndarray, " free"]
) -> Float[np.ndarray, "free free"]:
    K = _stiffness(model, y)
    return np.asarray(K)[np.ix_(free, free)]


@fast_compile_jit
def _stiffness(model: AbstractElasticModel, y: State) -> DofMatrix:
    return model.stiffness_matrix(y)


def _missing_constraints(k_ff: Float[np.ndarray, "free free"]) -> int:
    return np.shape(k_ff)[0] - numerical_rank(k_ff)


def static_equilibrium(
    model: AbstractElasticModel,
    y_guess: ArrayInput,
    prescribed: ArrayInput | None = None,
    forces: ArrayInput | None = None,
    *,
    rtol: float = 1e-10,
    atol: float = 1e-10,
    max_steps: int = 256,
) -> Equilibrium:
    """Solve $\\partial\\Pi/\\partial Y = G + F$ for the free coordinates.

    The prescribed coordinates keep their values from `y_guess`. The free ones are
    found in two stages with optimistix: BFGS with a line search descends the
    potential energy $V = \\Pi + \\sum_i m_i g z_i - F\\cdot Y$ (whose gradient is
    the force imbalance, so a start where the stiffness is singular still moves),
    then Levenberg-Marquardt (a trust-region Newton method) drives the imbalance
    $r = [\\partial\\Pi/\\partial Y - G - F]_f$ to zero. The result is a minimum
    of $V$: a stable equilibrium.

    The solution is unique only if the stiffness restricted to the free coordinates,
    $K_{ff}$, is non-singular there; in statics only rank K of the $6m + 6$
    equations are independent, so at least $6m + 6 - \\operatorname{rank} K$
    coordinates must be prescribed. Otherwise a `ValueError` says how many
    constraints are missing.

    **Arguments:**

    - `model`: an `ImmobileModel` or `MobileModel`.
    - `y_guess`: starting configuration, `(bodies, 6)`; holds the prescribed values.
    - `prescribed`: bool `(bodies, 6)`, true for a prescribed coordinate.
    - `forces`: constant generalized forces, `(m, 6)` on the contact bodies or
      `(m + 1, 6)`.
    - `rtol`, `atol`: tolerances of the solver.
    - `max_steps`: the most iterations.

    **Returns:** an `Equilibrium`.
    """
    # the tolerances and the iteration budget checked as the simulation's are
    SimulationOptions(
        rtol=rtol, atol=atol, max_steps=max_steps, owner="static_equilibrium"
    )
    traced = [
        name
        for name, value in (("model", model), ("y_guess", y_guess), ("forces", forces))
        if not is_concrete(value)
    ]
    if traced:
        raise ValueError(
            f"static_equilibrium takes concrete values (it reports the rank of the "
            f"stiffness and the constraints missing), got a traced {traced[0]} "
            f"(under jit, vmap or grad); elasticoop.rest_state finds the same rest "
            f"state and can be traced and differentiated"
        )
    n = model.n_bodies
    y_guess = jnp.asarray(as_float_array(y_guess, "y_guess", (n, 6)))
    mask = as_mask(prescribed, n)
    F = constant_forces(forces, n)
    free = np.flatnonzero(~mask.reshape(-1))
    if free.size == 0:
        raise ValueError("prescribed fixes every coordinate: nothing to solve for")

    found = _solve(model, y_guess, jnp.asarray(free), F, rtol, atol, max_steps)
    residual: Array | float
    y, residual, converged, steps, stiffness, total = found
    k_ff = np.asarray(stiffness)[np.ix_(free, free)]
    missing = _missing_constraints(k_ff)
    residual = float(residual)
    if missing > 0 or not bool(converged):
        at_guess = _missing_constraints(_restricted_stiffness(model, y_guess, free))
        missing = max(missing, at_guess)
        if missing > 0:
            need = model.n_prescribed(y_guess)
            raise ValueError(
                f"the static equilibrium is not unique: {int(mask.sum())} "
                f"coordinates are prescribed, but the stiffness restricted to the "
                f"{free.size} free ones is singular, so {missing} constraint"
                f"{'s are' if missing > 1 else ' is'} missing (6m + 6 - rank K = "
                f"{need} coordinates must be prescribed, and they must fix the "
                f"stiffness' null directions); prescribe {missing} more "
                f"coordinate{'s' if missing > 1 else ''}"
            )
        raise ValueError(
            f"the static equilibrium solver did not converge in {max_steps} steps "
            f"(largest force imbalance {residual:.3e}); start closer to the "
            f"equilibrium or raise max_steps"
        )
    reaction = jnp.asarray(np.where(mask, np.asarray(total), 0.0))
    return Equilibrium(
        y=y,
        reaction=reaction,
        residual=jnp.asarray(residual),
        stiffness=jnp.asarray(k_ff),
        mask_tuple=tuple(tuple(bool(v) for v in row) for row in np.asarray(mask)),
        steps=int(steps),
    )


def _full(y_free: Float[Array, " free"], args: _Args) -> State:
    model, y_guess, free, F = args
    return y_guess.reshape(-1).at[free].set(y_free).reshape(model.n_bodies, 6)


def _imbalance(y_free: Float[Array, " free"], args: _Args) -> Float[Array, " free"]:
    model, _, free, F = args
    y = _full(y_free, args)
    r = elastic_forces(model, y) - model.gravity_forces() - F
    return r.reshape(-1)[free]


def _energy(y_free: Float[Array, " free"], args: _Args) -> Scalar:
    model, _, _, F = args
    y = _full(y_free, args)
    return model.potential(y) + model.gravity_potential(y) - jnp.sum(F * y)


# Stored: in a fresh process (`elasticoop check`), tracing the two solvers would
# take most of the time of loading a scenario that starts from its equilibrium.
@stored_program
@fast_compile_jit
def _solve(
    model: AbstractElasticModel,
    y_guess: State,
    free: Int[Array, " free"],
    F: State,
    rtol: float,
    atol: float,
    max_steps: int,
) -> tuple[State, Scalar, Bool[Array, ""] | bool, Int[Array, ""], DofMatrix, State]:
    import optimistix as optx  # imported when a solve is traced

    args = (model, y_guess, free, F)
    # Descend the potential energy first: its gradient is the force imbalance, so
    # a start where the stiffness is singular (a link unloaded and stiff only
    # along itself) still moves towards the loaded, stable equilibrium...
    descent: optx.Solution[Float[Array, " free"], None] = optx.minimise(
        _energy,
        optx.BFGS(rtol=rtol, atol=atol),
        y_guess.reshape(-1)[free],
        args=args,
        max_steps=max_steps,
        throw=False,
    )
    # ...then polish the force balance with a trust-region Newton method.
    solution: optx.Solution[Float[Array, " free"], None] = optx.least_squares(
        _imbalance,
        optx.LevenbergMarquardt(rtol=rtol, atol=atol),
        descent.value,
        args=args,
        max_steps=max_steps,
        throw=False,
    )
    y = _full(solution.value, args)
    residual = jnp.max(jnp.abs(_imbalance(solution.value, args)))
    converged = solution.result == optx.RESULTS.successful
    steps = descent.stats["num_steps"] + solution.stats["num_steps"]
    total = elastic_forces(model, y) - model.gravity_forces() - F
    return y, residual, converged, steps, model.stiffness_matrix(y), total
