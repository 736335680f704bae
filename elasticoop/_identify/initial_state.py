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
