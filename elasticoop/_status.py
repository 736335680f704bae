"""How a run ended: `Status` codes and the sentence that explains each."""

import enum

import numpy as np


class Status(enum.IntEnum):
    """Outcome of one simulation (`Trajectory.status`)."""

    SUCCESS = 0
    GIMBAL_LOCK = 1
    LINK_COLLAPSED = 2
    MAX_STEPS_REACHED = 3
    SOLVER_FAILED = 4
    # NaN or inf in the initial state, the forces, the accelerations or the step size
    NONFINITE = 5
    # the run reached a time outside the samples of a `SampledForce`
    OUTSIDE_FORCE_SAMPLES = 6
    # a traced model its constructor would refuse (a mass, moment, stiffness or
    # damping out of range): not simulated
    INVALID_MODEL = 7


def status_message(traj, body_names=None, connection_names=None) -> str:
    """A sentence describing `traj.status` (a single, un-batched `Trajectory`);
    the body or connection at fault is named by `body_names` and
    `connection_names` when given, else by its index."""
    status = Status(int(traj.status))
    t = float(traj.event_time)
    k = int(traj.event_index)

    def body(i: int) -> str:
        return f"body '{body_names[i]}'" if body_names else f"body {i}"

    if status == Status.SUCCESS:
        return "the simulation reached the final time"
    if status == Status.GIMBAL_LOCK:
        rotation = traj.model.rotation
        return rotation.gimbal_lock_message(
            f"gimbal lock: {body(k)} reached", f"below the threshold at t = {t:.9g} s"
        )
    if status == Status.LINK_COLLAPSED:
        i, j = (int(v) for v in np.asarray(traj.model.pairs)[k])
        link = f"'{connection_names[k]}'" if connection_names else f"{k}"
        ends = (
            f"'{body_names[i]}' and '{body_names[j]}'" if body_names else f"{i} and {j}"
        )
        return (
            f"connection {link} between bodies {ends} collapsed (|r_i - r_j| fell "
            f"below link_tol x rest length) at t = {t:.9g} s; its deflection has no "
            f"direction at zero length"
        )
    if status == Status.MAX_STEPS_REACHED:
        steps = "" if traj.n_steps is None else f" ({int(traj.n_steps)} steps)"
        return (
            f"the solver reached max_steps{steps} at t = {t:.9g} s; raise max_steps "
            f"or loosen rtol/atol, or check that the time span is what you meant and "
            f"how stiff the grasps are (stiffer grasps need smaller steps)"
        )
    if status == Status.NONFINITE:
        where = (
            f"the initial state or the forces of {body(k)}"
            if k >= 0
            else "the accelerations or the step size"
        )
        return (
            f"NaN or inf stopped the run at t = {t:.9g} s: {where} are not finite "
            f"there; check the forces (a force callable must return finite values) "
            f"and the model's parameters"
        )
    if status == Status.INVALID_MODEL:
        return (
            "the model was not simulated: it has values its constructor refuses (a "
            "mass or principal moment not positive, the triangle inequality of the "
            "moments broken, a negative or non-finite stiffness, damping, rest "
            "length or gravity); such a model reaches simulate only traced, e.g. "
            "from eqx.tree_at under jax.vmap or jax.jit"
        )
    if status == Status.OUTSIDE_FORCE_SAMPLES:
        return (
            f"the run reached t = {t:.9g} s, outside the times sampled by the "
            f"SampledForce; its samples must cover the simulated times (they are not "
            f"extrapolated)"
        )
    return (
        f"the solver failed at t = {t:.9g} s: the step size collapsed (a "
        f"discontinuity or a singularity the solver cannot pass, or a failed implicit "
        f"step)"
    )
