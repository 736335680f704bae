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


def status_message(traj) -> str:
    """A sentence describing `traj.status` (a single, un-batched `Trajectory`)."""
    status = Status(int(traj.status))
    t = float(traj.event_time)
    k = int(traj.event_index)
    if status == Status.SUCCESS:
        return "the simulation reached the final time"
    if status == Status.GIMBAL_LOCK:
        rotation = traj.model.rotation
        return rotation.gimbal_lock_message(
            f"gimbal lock: body {k} reached", f"below the threshold at t = {t:.9g} s"
        )
    if status == Status.LINK_COLLAPSED:
        i, j = (int(v) for v in np.asarray(traj.model.pairs)[k])
        return (
            f"connection {k} between bodies {i} and {j} collapsed (|r_i - r_j| fell "
            f"below link_tol x rest length) at t = {t:.9g} s; its deflection has no "
            f"direction at zero length"
        )
    if status == Status.MAX_STEPS_REACHED:
        return (
            f"the solver reached max_steps at t = {t:.9g} s; raise max_steps, loosen "
            f"rtol/atol or use an implicit solver for stiff grasps"
        )
    return f"the solver failed at t = {t:.9g} s (step size too small or NaN)"
