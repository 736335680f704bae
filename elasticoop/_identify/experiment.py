"""`Experiment`: one recorded motion (data), validated, and batched for `vmap`."""

from typing import Any

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._analysis import contact_bodies_held
from .._forces import AbstractForce, check_force
from .._validation import check_times
from .initial_state import initial_state_from_data


class Experiment(eqx.Module):
    """One recorded motion of the elastic system, the data of an identification.

    **Arguments:**

    - `ts`: sample times [s], strictly increasing, shape `(times,)`.
    - `y`: measured $Y(t)$, shape `(times, bodies, 6)`; NaN marks a missing sample.
    - `y_init`, `ydot_init`: the initial state $Y(t_0)$, $\\dot Y(t_0)$ the
      simulation starts from, shape `(bodies, 6)`: known values, or the start of
      their estimates when `identify(..., fit_initial=...)` estimates them. `None`
      (the default) takes them from the measured motion
      (`initial_state_from_data` with `window` and `polyorder`: the first sample
      of `y`, and the Savitzky-Golay derivative at $t_0$; uniformly spaced `ts`,
      the first `window` samples measured), or `ydot_init` from the first sample
      of a measured `ydot`. A
      rate taken from noisy data is only approximate: estimate it with the
      parameters (`fit_initial="rates"` or `"state"`) unless it is known.
    - `forces`: the applied forces, as accepted by `simulate` (`None`, an array
      `(m, 6)`, a `ConstantForce`, `SampledForce`, `PoseTracking`, any other
      `AbstractForce` or a callable). Leaves of the force that are not arrays (e.g.
      a Python float in a force of one's own) are constants: experiments batched
      together must agree on them.
    - `sigma`: noise level (standard deviation) of `y`: a scalar, one value per
      coordinate `(6,)` or per body and coordinate `(bodies, 6)`. Residuals are
      divided by it. `None` weights every coordinate by 1 and lets the fit estimate
      one common noise variance from the residuals.
    - `ydot`: optional measured $\\dot Y(t)$, shape `(times, bodies, 6)` (NaN =
      missing); fitted too when given (output error) and used instead of a smoothed
      derivative by the equation-error initialiser.
    - `sigma_ydot`: noise level of `ydot`, shaped like `sigma` (required with
      `ydot` when `sigma` is given).
    - `yddot`: optional measured $\\ddot Y(t)$ (used only by the equation-error
      initialiser).
    - `rest`: whether the experiment started at rest in static equilibrium:
      `None` (default: not known to), `True` (the contact bodies held at their
      poses in `y_init`, the object free, as `[initial] from = "equilibrium"`
      holds them) or a bool `(bodies, 6)` array of the held coordinates. With it,
      `identify` (its default `initial="auto"`) recomputes the initial state at
      every evaluation of the fit as the rest state of the parameters evaluated
      (`rest_state`, under the applied forces at rest at $t_0$, as numbers), with
      `y_init` holding the held poses and the start of the free coordinates.
    - `window`, `polyorder`: the differentiator that takes a missing `y_init` or
      `ydot_init` from the data (not stored).

    Bad data (wrong shapes, a time grid that does not match `y`, a body coordinate
    that is NaN in every sample, non-positive `sigma`) raises `ValueError`.
    """

    ts: jax.Array
    y: jax.Array
    y_init: jax.Array
    ydot_init: jax.Array
    forces: AbstractForce | None
    sigma: jax.Array | None
    ydot: jax.Array | None
    sigma_ydot: jax.Array | None
    yddot: jax.Array | None
    # the held coordinates of a start at rest (see `rest`), or None
    rest: tuple[tuple[bool, ...], ...] | None = eqx.field(static=True)

    def __init__(
        self,
        ts,
        y,
        y_init=None,
        ydot_init=None,
        forces=None,
        sigma=None,
        *,
        ydot=None,
        sigma_ydot=None,
        yddot=None,
        window: int = 21,
        polyorder: int = 4,
        rest=None,
    ):
        ts = check_times(ts, "Experiment.ts")
        n_times = ts.shape[0]
        y = _series(y, "Experiment.y", n_times)
        n_bodies = y.shape[1]
        if ydot is not None:
            ydot = _series(ydot, "Experiment.ydot", n_times, n_bodies)
            if ydot_init is None and np.all(np.isfinite(ydot[0])):
                ydot_init = ydot[0]  # measured
        if y_init is None or ydot_init is None:
            y_data, ydot_data = initial_state_from_data(
                ts, y, window, polyorder, "Experiment.y"
            )
            y_init = y_data if y_init is None else y_init
            ydot_init = ydot_data if ydot_init is None else ydot_init
        y_init = _state(y_init, "Experiment.y_init", n_bodies)
        ydot_init = _state(ydot_init, "Experiment.ydot_init", n_bodies)
        if yddot is not None:
            yddot = _series(yddot, "Experiment.yddot", n_times, n_bodies, nan_ok=False)
        if sigma is not None:
            sigma = _sigma(sigma, "Experiment.sigma", n_bodies)
        if sigma_ydot is not None:
            if ydot is None:
                raise ValueError("Experiment.sigma_ydot was given without ydot")
            sigma_ydot = _sigma(sigma_ydot, "Experiment.sigma_ydot", n_bodies)
        elif ydot is not None and sigma is not None:
            raise ValueError(
                "Experiment.sigma_ydot is required when both sigma and ydot are given"
            )
        force = check_force(
            forces,
            jnp.asarray(y_init),
            jnp.asarray(ydot_init),
            jnp.asarray(ts),
            "Experiment.",
        )
        self.ts = jnp.asarray(ts)
        self.y = jnp.asarray(y)
        self.y_init = jnp.asarray(y_init)
        self.ydot_init = jnp.asarray(ydot_init)
        self.forces = force
        self.sigma = None if sigma is None else jnp.asarray(sigma)
        self.ydot = None if ydot is None else jnp.asarray(ydot)
        self.sigma_ydot = None if sigma_ydot is None else jnp.asarray(sigma_ydot)
        self.yddot = None if yddot is None else jnp.asarray(yddot)
        self.rest = _rest(rest, n_bodies)

    @property
    def n_bodies(self) -> int:
        return int(self.y.shape[-2])

    @property
    def n_samples(self) -> int:
        """Number of measured (non-NaN) values in `y` and `ydot`."""
        n = int(np.sum(np.isfinite(np.asarray(self.y))))
        if self.ydot is not None:
            n += int(np.sum(np.isfinite(np.asarray(self.ydot))))
        return n


def _rest(value, n_bodies) -> tuple[tuple[bool, ...], ...] | None:
    if value is None or value is False:
        return None
    if value is True:
        mask = contact_bodies_held(n_bodies)
    else:
        mask = np.asarray(value)
        if mask.dtype != np.bool_ or mask.shape != (n_bodies, 6):
            raise ValueError(
                f"Experiment.rest must be None, True or a bool array of shape "
                f"({n_bodies}, 6) (the held coordinates), got {value!r}"
            )
        if mask.all():
            raise ValueError("Experiment.rest holds every coordinate: none is free")
    return tuple(tuple(bool(v) for v in row) for row in mask)


def _array(value, name):
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be an array of numbers, got {value!r}") from None


def _series(value, name, n_times, n_bodies=None, nan_ok=True):
    arr = _array(value, name)
    if arr.ndim != 3 or arr.shape[2] != 6:
        raise ValueError(
            f"{name} must have shape (times, bodies, 6), got shape {arr.shape}"
        )
    if arr.shape[0] != n_times:
        raise ValueError(
            f"{name} has {arr.shape[0]} samples but Experiment.ts has {n_times} "
            f"times (the time grids do not match)"
        )
    if n_bodies is not None and arr.shape[1] != n_bodies:
        raise ValueError(
            f"{name} has {arr.shape[1]} bodies but Experiment.y has {n_bodies}"
        )
    if np.any(np.isinf(arr)):
        raise ValueError(f"{name} must not contain inf (use NaN for missing samples)")
    missing = np.all(np.isnan(arr), axis=0)
    if not nan_ok and np.any(np.isnan(arr)):
        raise ValueError(f"{name} must not contain NaN")
    if np.any(missing):
        body, coord = (int(k) for k in np.argwhere(missing)[0])
        raise ValueError(
            f"{name}[:, {body}, {coord}] is NaN in every sample: body {body}, "
            f"coordinate {coord} has no data (give NaN only for missing samples)"
        )
    return arr


def _state(value, name, n_bodies):
    arr = _array(value, name)
    if arr.ndim == 2 and arr.shape[1] == 6 and arr.shape[0] != n_bodies:
        # (which of the two is wrong is not known here: both are named)
        raise ValueError(
            f"{name} and Experiment.y must have the same bodies, got {name} of "
            f"shape {arr.shape} ({arr.shape[0]} bodies) and samples of "
            f"Experiment.y of shape ({n_bodies}, 6)"
        )
    if arr.shape != (n_bodies, 6):
        raise ValueError(
            f"{name} must have shape ({n_bodies}, 6) like one sample of "
            f"Experiment.y, got shape {arr.shape}"
        )
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{name} must be finite")
    return arr


def _sigma(value, name, n_bodies):
    arr = _array(value, name)
    if arr.shape not in ((), (6,), (n_bodies, 6)):
        raise ValueError(
            f"{name} must be a scalar, shape (6,) or ({n_bodies}, 6), got shape "
            f"{arr.shape}"
        )
    if not np.all(np.isfinite(arr) & (arr > 0)):
        raise ValueError(f"{name} must be positive and finite, got {arr}")
    return np.broadcast_to(arr, (n_bodies, 6)).copy()


def check_experiments(model, experiments) -> list[Experiment]:
    """Validate a sequence of experiments against `model` (bodies, uniform
    weighting) and return them as a list."""
    if isinstance(experiments, Experiment):
        experiments = [experiments]
    experiments = list(experiments)
    if not experiments:
        raise ValueError("experiments must hold at least one Experiment")
    for k, e in enumerate(experiments):
        if not isinstance(e, Experiment):
            raise ValueError(
                f"experiments[{k}] must be an Experiment, got {type(e).__name__}"
            )
        if e.n_bodies != model.n_bodies:
            raise ValueError(
                f"experiments[{k}].y has {e.n_bodies} bodies but the model has "
                f"{model.n_bodies}"
            )
    given = {e.sigma is not None for e in experiments}
    if len(given) > 1:
        raise ValueError(
            "give sigma for every experiment or for none (the noise level is "
            "either known everywhere or estimated from the residuals)"
        )
    return experiments


def _constant_key(value: Any) -> Any:
    """A non-array leaf as part of a batch's signature: itself when hashable (equal
    constants batch together), otherwise its identity."""
    try:
        hash(value)
    except TypeError:
        return ("object", id(value))
    return ("constant", type(value), value)


def _signature(e: Experiment):
    """What experiments batched together share: the tree structure, the shape and
    dtype of every array leaf, and the value of every other leaf (a constant of a
    force, e.g. a Python float)."""
    leaves, treedef = jax.tree.flatten(e)
    return treedef, tuple(
        (x.shape, x.dtype) if eqx.is_array(x) else _constant_key(x) for x in leaves
    )


def _stack(*xs):
    """Array leaves stacked along a new leading axis; constants, equal across the
    batch, kept once."""
    return jnp.stack(xs) if eqx.is_array(xs[0]) else xs[0]


def batch_experiments(experiments) -> list[tuple[list[int], Experiment]]:
    """Group experiments of equal shapes (and equal non-array leaves, e.g. the
    Python floats of a force) and stack each group's arrays along a new leading
    axis, so that a group is simulated by one `vmap`-ed call
    (`equinox.filter_vmap`: the non-array leaves are not mapped over).

    **Returns:** a list of `(indices, stacked)`, `indices` naming the experiments
    of the group in input order.
    """
    groups: dict = {}
    for k, e in enumerate(experiments):
        groups.setdefault(_signature(e), []).append(k)
    out = []
    for indices in groups.values():
        members = [experiments[k] for k in indices]
        stacked = jax.tree.map(_stack, *members)
        out.append((indices, stacked))
    return out
