"""The initial state of an experiment: taken from the measured motion, or estimated
together with the parameters.

Measured motion rarely comes with an exactly known initial state $Y(t_0)$,
$\\dot Y(t_0)$. Two routes replace it:

- **From the data** (`initial_state_from_data`): $\\hat Y(t_0)$ is the first
  sample (its noise is that of the data; the smoothing polynomial's value there
  would be biased by motion faster than the window), and $\\hat{\\dot Y}(t_0)$
  is the derivative at $t_0$ of the Savitzky-Golay polynomial of degree
  `polyorder` fitted by least squares to the first `window` samples. At the end
  of the record the fit is one-sided, so the rate is the noisiest estimate the
  filter makes: for white noise of level $\\sigma$ on samples $h$ apart its
  standard error is $c\\,\\sigma / (h\\,\\text{window}^{3/2})$, with $c \\approx 13$
  for `polyorder` 2 and $c \\approx 60$ for `polyorder` 4 (e.g.
  $1.2\\cdot 10^{-3}$ m/s for $\\sigma = 10^{-5}$ m, $h = 5$ ms, a window of 21,
  degree 4), and motion faster than the window biases it. It is a start, or an
  approximation where the initial state is not estimated, not a measurement.
- **Estimated with the parameters** (`identify(..., fit_initial=...)`): the fit's
  unknowns become $(u, \\Delta_e)$, with $\\Delta_e$ the correction of experiment
  $e$'s initial positions ($Y_e(t_0) = \\hat Y_e(t_0) + \\Delta^Y_e$), rates
  ($\\dot Y_e(t_0) = \\hat{\\dot Y}_e(t_0) + \\Delta^{\\dot Y}_e$) or both, all
  starting from 0; here $\\hat Y_e(t_0)$, $\\hat{\\dot Y}_e(t_0)$ are the
  experiment's `y_init`, `ydot_init` (given, or taken from the data). The
  output-error residuals then depend on $\\Delta_e$ through the simulation, and
  the sensitivities $\\partial r/\\partial\\Delta_e$ come from
  the same forward-mode integration as those of the parameters. The standard
  errors of the parameters account for the estimated initial states (they are
  nuisance parameters: see `gauss_newton_uncertainty`'s `nuisance`).
"""

import dataclasses

import numpy as np

from .._naming import coordinate_names, default_body_names
from .differentiate import savitzky_golay

# What `identify(fit_initial=...)` may estimate: the name and, per part, whether the
# positions Y(t0) and the rates Y'(t0) are estimated.
FIT_INITIAL = {
    "none": (False, False),
    "positions": (True, False),
    "rates": (False, True),
    "state": (True, True),
}


def fitted_parts(fit_initial: str) -> tuple[bool, bool]:
    """`(positions, rates)`: which parts of the initial state `fit_initial` names."""
    try:
        return FIT_INITIAL[fit_initial]
    except (KeyError, TypeError):
        raise ValueError(
            f"fit_initial must be one of {sorted(FIT_INITIAL)} (the parts of each "
            f"experiment's initial state estimated with the parameters), got "
            f"{fit_initial!r}"
        ) from None


def initial_state_from_data(
    ts, y, window: int = 21, polyorder: int = 4, name: str = "y"
) -> tuple[np.ndarray, np.ndarray]:
    """$\\hat Y(t_0)$ and $\\hat{\\dot Y}(t_0)$ from uniformly sampled motion: the
    first sample, and the derivative at `ts[0]` of the polynomial of degree
    `polyorder` fitted by least squares to the first `window` samples (the
    Savitzky-Golay differentiator, `savitzky_golay`).

    **Arguments:**

    - `ts`: uniformly spaced sample times, shape `(times,)`.
    - `y`: measured $Y$, shape `(times, bodies, 6)`; the first `window` samples of
      every coordinate must be measured (not NaN).
    - `window`, `polyorder`: the differentiator's window (odd number of samples)
      and polynomial degree (>= 1).
    - `name`: the name of `y` in error messages.

    **Returns:** `(y_init, ydot_init)`, each of shape `(bodies, 6)`.
    """
    y = np.asarray(y, dtype=np.float64)
    if polyorder < 1:
        raise ValueError(
            f"the initial rates need polyorder >= 1 in the differentiator, got "
            f"{polyorder!r}"
        )
    ts = np.asarray(ts, dtype=np.float64)
    first = y[:window]
    missing = np.argwhere(~np.all(np.isfinite(first), axis=0))
    if missing.size and first.shape[0] == window:
        body, coord = (int(k) for k in missing[0])
        raise ValueError(
            f"the initial state cannot be taken from {name}: {name}[:{window}, "
            f"{body}, {coord}] (body {body}, coordinate {coord}) has missing "
            f"samples within the first {window} samples, the differentiator's "
            f"window; give the initial state, or a smaller window"
        )
    try:
        # the first window's polynomial is all the rate at ts[0] depends on
        (rate,) = savitzky_golay(
            first, ts[: first.shape[0]], window, polyorder, derivs=(1,)
        )
    except ValueError as error:
        raise ValueError(
            f"the initial state cannot be taken from {name}: {error} (or give "
            f"the initial state)"
        ) from None
    # the first sample itself: unbiased, while the one-sided polynomial's value at
    # t0 is biased by motion faster than the window
    y0, ydot0 = y[0], rate[0]
    return y0, ydot0


def initial_state_names(
    order,
    n_bodies: int,
    convention: str,
    fit_initial: str,
    body_names=None,
) -> tuple[str, ...]:
    """Names of the estimated initial-state entries in the order of the fit's
    unknowns: per experiment (`order`: the experiments' indices in that order), the
    positions (if estimated) then the rates, body-major, e.g.
    `experiment[0].ydot_init.contact1.z`."""
    positions, rates = fitted_parts(fit_initial)
    bodies = default_body_names(n_bodies) if body_names is None else body_names
    coords = coordinate_names(convention)
    parts = [p for p, on in (("y_init", positions), ("ydot_init", rates)) if on]
    return tuple(
        f"experiment[{k}].{part}.{b}.{c}"
        for k in order
        for part in parts
        for b in bodies
        for c in coords
    )


# The values of `identify(initial=...)`: how each experiment's initial state is set.
INITIAL_RULES = ("auto", "equilibrium", "frozen", "data", "fitted")


def initial_rule(initial, fit_initial, experiments, window, polyorder, notes):
    """Apply `identify`'s `initial` rule to the experiments.

    - `"auto"`: `"equilibrium"` for the experiments that started at rest
      (`Experiment.rest`), their own `y_init`, `ydot_init` for the others.
    - `"equilibrium"`: every experiment started at rest (those without
      `Experiment.rest` with the contact bodies held at their poses in
      `y_init`): its initial state is the rest state of the parameters
      evaluated, recomputed at every evaluation of the fit.
    - `"frozen"`: the experiments' `y_init`, `ydot_init` as they are (for an
      experiment at rest: the rest state of the model passed in, not
      recomputed).
    - `"data"`: taken from each experiment's first samples
      (`initial_state_from_data` with `window`, `polyorder`).
    - `"fitted"`: estimated with the parameters (`fit_initial="state"`), starting
      from the experiments' own.

    **Returns:** `(experiments, fit_initial, rest)`: the experiments to fit,
    the `fit_initial` to use, and whether rest states are recomputed. Appends what
    was done to `notes`.
    """
    if initial not in INITIAL_RULES:
        raise ValueError(
            f"initial must be one of {INITIAL_RULES} (how each experiment's "
            f"initial state is set), got {initial!r}"
        )
    fitted_parts(fit_initial)  # checked
    if fit_initial != "none" and initial == "equilibrium":
        raise ValueError(
            f"initial={initial!r} recomputes the initial state from the parameters; "
            f"it cannot also be estimated (fit_initial={fit_initial!r})"
        )
    at_rest = [e.rest is not None for e in experiments]
    if initial == "fitted":
        if fit_initial not in ("none", "state"):
            raise ValueError(
                f"initial='fitted' estimates the whole initial state; "
                f"fit_initial={fit_initial!r} names a part of it"
            )
        notes.append(
            "initial state of each experiment estimated with the parameters "
            "(initial = fitted)"
        )
        return experiments, "state", False
    if initial == "data":
        out = []
        for k, e in enumerate(experiments):
            y0, ydot0 = initial_state_from_data(
                e.ts, e.y, window, polyorder, f"experiments[{k}].y"
            )
            out.append(dataclasses.replace(e, y_init=y0, ydot_init=ydot0))
        notes.append(
            "initial state of each experiment taken from its first samples "
            "(initial = data: the first sample, and the Savitzky-Golay rate)"
        )
        return out, fit_initial, False
    if (
        initial == "frozen"
        or fit_initial != "none"
        or (initial == "auto" and not any(at_rest))
    ):
        if initial == "frozen" and any(at_rest):
            notes.append(
                "initial state frozen (initial = frozen): the experiments at rest "
                "start from the equilibrium of the starting model, not recomputed"
            )
        return experiments, fit_initial, False
    if initial == "equilibrium":
        experiments = [
            e
            if e.rest is not None
            else dataclasses.replace(
                e, rest=True, ydot_init=np.zeros(np.shape(e.ydot_init))
            )
            for e in experiments
        ]
    notes.append(
        "initial state at rest in the static equilibrium of the parameters evaluated, "
        "recomputed at every evaluation (initial = equilibrium; the held "
        "coordinates at their commanded poses, the applied forces as numbers)"
    )
    return experiments, fit_initial, True
