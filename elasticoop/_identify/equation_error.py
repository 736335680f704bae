"""Equation-error estimate: one linear least-squares problem, no simulation.

Lagrange's equations, read as a residual of the measured motion,
$$e(p; t_k) = W(Y)\\ddot Y + w(Y, \\dot Y; p) - G - F$$
(zero for the true $p$),
are *affine* in the stiffness and damping parameters ($\\Pi$ and $R$ are linear in
them) and in the masses and inertias ($T$ and the gravity potential are linear in
them). So with $e_0 = e(p_0)$ and $A = \\partial e/\\partial p$ (both by autodiff of
`inverse_dynamics`, i.e. of $T$, $\\Pi$ and $R$) the minimiser of $\\sum_k |e|^2$ is
$p = p_0 - A^+ e_0$: one linear least-squares solve (a Gauss-Newton step for a
parameter that enters non-linearly). The columns are scaled by $|p_0|$ first.

Entries that the samples do not determine keep their values in the model: those
along a null direction of $A$ or with a relative standard error above
`max_relative_stderr` (50 %), by the same Gauss-Newton uncertainty as `identify`'s
flags (`gauss_newton_uncertainty`, the noise scale from the residuals), and the
others are solved for again with them held. With noisy samples, a parameter the
motion does not excite (a rotational stiffness in a lift without rotation) would
otherwise be fitted to the noise of the differentiated data: to 1.1 where the model
holds 40, with a standard error of 2000 times the estimate.

$\\dot Y$ and $\\ddot Y$ are taken from the experiment when measured, otherwise
estimated by the Savitzky-Golay smoothing differentiator (`savitzky_golay`), which
then also supplies the smoothed $Y$. Samples whose window holds a missing value are
left out.
"""

import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._forces import pad_to_bodies
from .._lagrange import inverse_dynamics
from .differentiate import savitzky_golay
from .experiment import Experiment, check_experiments
from .parameters import FreeParameters, free_parameters
from .uncertainty import gauss_newton_uncertainty


def motion_estimates(e: Experiment, window: int = 21, polyorder: int = 4):
    """$Y$, $\\dot Y$, $\\ddot Y$ at the sample times of `e`: measured ones where
    given, otherwise from the Savitzky-Golay differentiator."""
    y = np.asarray(e.y)
    if e.ydot is not None and e.yddot is not None:
        return y, np.asarray(e.ydot), np.asarray(e.yddot)
    smooth, dy, ddy = savitzky_golay(y, e.ts, window, polyorder, derivs=(0, 1, 2))
    if e.ydot is not None:
        dy = np.asarray(e.ydot)
        (ddy,) = savitzky_golay(dy, e.ts, window, polyorder, derivs=(1,))
    if e.yddot is not None:
        ddy = np.asarray(e.yddot)
    return smooth, dy, ddy


@eqx.filter_jit
def _affine_system(model, free: FreeParameters, p0, ts, y, ydot, yddot, force):
    def residual(p):
        fitted = free.apply(model, p)

        def one(t, q, v, a):
            applied = jnp.zeros_like(q)
            if force is not None:
                applied = pad_to_bodies(force(t, q, v), q.shape[0])
            return inverse_dynamics(fitted, q, v, a) - applied

        return jax.vmap(one)(ts, y, ydot, yddot).reshape(-1)

    e0 = residual(p0)
    return e0, jax.jacfwd(residual)(p0)


def equation_error(
    model,
    experiments,
    where,
    *,
    window: int = 21,
    polyorder: int = 4,
    mask=None,
):
    """Estimate the free parameters by equation error (see the module docstring):
    the entries the samples determine, the others at the model's values.

    **Arguments:**

    - `model`: the model; its values of the free leaves are the point $p_0$ the
      (affine) residual is expanded about, and the values of all other leaves are
      taken as known.
    - `experiments`: an `Experiment` or a sequence of them.
    - `where`: selects the free leaves, e.g. `lambda m: (m.stiffness, m.damping)`.
    - `window`, `polyorder`: the Savitzky-Golay window (odd number of samples) and
      polynomial degree, used where $\\dot Y$ or $\\ddot Y$ were not measured.
    - `mask`: the free entries of the selected leaves, as for `identify`.

    **Returns:** `model` with the free leaves set to the least-squares estimate
    (the entries it does not determine at their values in `model`). With noisy
    data an estimate may leave the physical range (e.g. a negative damping);
    `identify` then starts that entry from the value in `model`.
    """
    return estimate_by_equation_error(
        model, experiments, where, window=window, polyorder=polyorder, mask=mask
    )[0]


def estimate_by_equation_error(
    model,
    experiments,
    where,
    *,
    window: int = 21,
    polyorder: int = 4,
    mask=None,
    rcond: float = 1e-8,
    max_relative_stderr: float = 0.5,
):
    """`equation_error`'s model, and which free entries the samples do not
    determine (a bool array over them, true where the model's value was kept):
    those along a null direction (`rcond`) or with a relative standard error above
    `max_relative_stderr`, as `identify` flags its estimates."""
    experiments = check_experiments(model, experiments)
    free = free_parameters(model, where, "identity", mask)
    p0 = np.asarray(free.current(model), dtype=np.float64)
    blocks, rhs = [], []
    for k, e in enumerate(experiments):
        y, ydot, yddot = motion_estimates(e, window, polyorder)
        keep = np.all(np.isfinite(y) & np.isfinite(ydot) & np.isfinite(yddot), (1, 2))
        if not np.any(keep):
            raise ValueError(
                f"experiments[{k}] has no sample where the motion and its "
                f"derivatives are known (too many missing samples for the "
                f"smoothing window of {window})"
            )
        e0, A = _affine_system(
            model,
            free,
            jnp.asarray(p0),
            jnp.asarray(np.asarray(e.ts)[keep]),
            jnp.asarray(y[keep]),
            jnp.asarray(ydot[keep]),
            jnp.asarray(yddot[keep]),
            e.forces,
        )
        blocks.append(np.asarray(A))
        rhs.append(np.asarray(e0))
    A, e0 = np.concatenate(blocks), np.concatenate(rhs)
    scale = np.where(p0 != 0, np.abs(p0), 1.0)
    p = _solved(A, e0, p0, scale, np.ones(p0.shape, bool))
    with warnings.catch_warnings():  # (non-finite input: nothing is held)
        warnings.simplefilter("ignore", RuntimeWarning)
        uncertainty = gauss_newton_uncertainty(
            e0 + A @ (p - p0),
            A,
            p,
            noise_known=False,
            rcond=rcond,
            max_relative_stderr=max_relative_stderr,
            names=free.names,
        )
    undetermined = np.zeros(p0.shape, bool)
    if not uncertainty.reason:
        undetermined = ~uncertainty.identifiable
    if np.any(undetermined):
        p = _solved(A, e0, p0, scale, ~undetermined)
    return free.apply(model, jnp.asarray(p)), undetermined


def _solved(A, e0, p0, scale, free):
    """$p_0 - A^+ e_0$ in the entries `free` (columns scaled by `scale`), the
    others at $p_0$."""
    p = p0.copy()
    if np.any(free):
        step, *_ = np.linalg.lstsq(A[:, free] * scale[None, free], e0, rcond=None)
        p[free] = p0[free] - scale[free] * step
    return p
