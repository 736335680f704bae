"""The two scenarios the solver and gradient benchmarks run: the built-in two-arm
lift and a stiff variant of it (light grasp bodies, stiff connections)."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import elasticoop as eo
from elasticoop import default_scenario

# Stiff variant: grasp bodies 10x lighter, connections 10x stiffer and 3x more damped.
STIFF_MASS, STIFF_INERTIA = 0.03, 1.2e-4
STIFF_K, STIFF_D = 10.0, 3.0


def stiff_scenario(n_output: int = 301):
    """`default_scenario()` with light grasps and stiff, damped connections."""
    s = default_scenario(n_output)
    model = s.model
    mass = model.bodies.mass.at[1:].set(STIFF_MASS)
    inertia = model.bodies.inertia.at[1:].set(STIFF_INERTIA)
    model = eqx.tree_at(
        lambda m: (m.bodies.mass, m.bodies.inertia, m.stiffness, m.damping),
        model,
        (mass, inertia, STIFF_K * model.stiffness, STIFF_D * model.damping),
    )
    weight = 0.5 * float(jnp.sum(mass)) * float(model.gravity)
    forces = eqx.tree_at(
        lambda f: f.feedforward, s.forces, s.forces.feedforward.at[:, 2].set(weight)
    )
    return eqx.tree_at(lambda sc: (sc.model, sc.forces), s, (model, forces))


def vector_field(t, state, args):
    """The first-order system `simulate` integrates, $(\\dot Y, \\ddot Y)$, from
    the library's `accelerations` and the scenario's force (`args = (model,
    force)`, force `None` or `f(t, y, ydot)` of shape `(m, 6)` or `(m + 1, 6)`),
    on the pair `(Y, Y')` (`simulate` packs the same system, with the work and
    the dissipated energy, into one vector)."""
    model, force = args
    y, ydot = state
    if force is None:
        applied = jnp.zeros_like(y)
    else:
        applied = force(t, y, ydot)
        if applied.shape[0] == y.shape[0] - 1:
            applied = jnp.concatenate([jnp.zeros_like(applied[:1]), applied])
    return ydot, eo.accelerations(model, y, ydot, applied)[0]


def scenarios(n_output: int = 301) -> dict:
    return {"default": default_scenario(n_output), "stiff": stiff_scenario(n_output)}


def stiffness_ratio(scenario) -> float:
    """$\\max|\\lambda| \\cdot T$: the fastest eigenvalue of the Jacobian of the
    first-order vector field at the initial state, times the lift duration
    $T = 2$ s (the time scale of the object's motion)."""
    s = scenario
    n = s.model.n_bodies

    def field(state):
        y, v = state[: 6 * n].reshape(n, 6), state[6 * n :].reshape(n, 6)
        dy, dv = vector_field(0.0, (y, v), (s.model, s.forces))
        return jnp.concatenate([dy.ravel(), dv.ravel()])

    state = jnp.concatenate([s.y_init.ravel(), s.ydot_init.ravel()])
    eig = np.linalg.eigvals(np.asarray(jax.jacfwd(field)(state)))
    return float(np.max(np.abs(eig)) * s.forces.duration)
