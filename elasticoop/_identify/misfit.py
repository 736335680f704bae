"""Does the fitted model explain the data? The residuals against the noise.

At the estimate, with $r$ the residuals divided by the noise level $\\sigma$ of
each measured channel (experiment, body, coordinate), $N$ measured samples and
$n_p$ fitted unknowns, a model that explains the data leaves
$$\\chi^2_\\nu = \\frac{\\sum r^2}{N - n_p} \\approx 1$$
(the noise floor of the loss $\\tfrac12\\sum r^2$ is $\\tfrac12 (N - n_p)$).

- **Declared noise** (`Experiment.sigma`): the fit is a **misfit** when
  $\\chi^2_\\nu$ exceeds `MISFIT_THRESHOLD` (4: residuals twice the noise, RMS).
- **No declared noise**: the residuals' size cannot be judged against a noise
  level the fit itself estimates, so their structure is: noise leaves residuals
  that are uncorrelated from one sample to the next, while a model that does not
  explain the data leaves smooth, correlated ones. The fit is a misfit when the
  pooled lag-1 autocorrelation of the residuals along time,
  $\\rho_1 = \\sum r_k r_{k+1} / \\sum r_k^2$ over the channels, exceeds
  `AUTOCORRELATION_THRESHOLD` (0.5; about 0 $\\pm 1/\\sqrt N$ for white
  noise), unless the residuals are within the simulation's own accuracy
  ($10\\,(\\text{rtol}\\,|y|_{\\max} + \\text{atol})$ per channel: noise-free
  data fitted exactly). $\\chi^2_\\nu$ is then reported against the noise the
  data's own second differences imply,
  $\\hat\\sigma_c^2 = \\overline{(y_{k+1} - 2y_k + y_{k-1})^2}/6$ per channel
  (exact for white noise on a straight line, larger where the motion is fast
  against the sampling).
"""

import dataclasses

import numpy as np

from .._naming import coordinate_names

MISFIT_THRESHOLD = 4.0
AUTOCORRELATION_THRESHOLD = 0.5
# How many channels the report names.
WORST_SHOWN = 3


@dataclasses.dataclass(frozen=True)
class WorstChannel:
    """A channel with large residuals: its experiment, body and coordinate, the
    mean square of its residuals over the noise variance, and the time of its
    largest residual."""

    experiment: int
    body: int
    coordinate: int  # 0..5: Y; 6..11: the rate of coordinate - 6
    ratio: float
    time: float


@dataclasses.dataclass(frozen=True)
class MisfitCheck:
    """The residuals against the noise (see the module's docstring).

    - `ratio`: $\\chi^2_\\nu$, the mean square of the residuals over the noise
      variance per degree of freedom.
    - `threshold`: the misfit threshold on it.
    - `declared`: whether the noise level is the data's declared one (else
      implied by their second differences).
    - `noise_floor`: the loss the noise alone explains, $\\tfrac12 (N - n_p)$
      in units of the declared noise (the fit's own loss units).
    - `worst`: the channels with the largest ratio, largest first.
    - `autocorrelation`: the pooled lag-1 autocorrelation of the residuals above
      the simulation's accuracy (NaN where none are).
    """

    ratio: float
    threshold: float
    declared: bool
    noise_floor: float
    worst: tuple[WorstChannel, ...] = ()
    autocorrelation: float = float("nan")

    @property
    def misfit(self) -> bool:
        if not np.isfinite(self.ratio):
            return True
        if self.declared:
            return bool(self.ratio > self.threshold)
        return bool(self.autocorrelation > AUTOCORRELATION_THRESHOLD)

    def channel_name(self, w: WorstChannel, body_names, convention: str) -> str:
        coords = coordinate_names(convention)
        c = coords[w.coordinate % 6]
        what = f"{body_names[w.body]}.{c}"
        if w.coordinate >= 6:
            what = f"rate of {what}"
        return f"experiment {w.experiment}: {what}"

    def describe(self, body_names, convention: str) -> str:
        """One sentence: the ratio against the threshold, and the worst channels
        with the time of their largest residual."""
        if self.declared:
            text = (
                f"the residuals are {self.ratio:.3g} times the declared noise (mean "
                f"square per degree of freedom; misfit above {self.threshold:g})"
            )
        else:
            text = (
                f"the residuals are correlated from sample to sample (lag-1 "
                f"autocorrelation {self.autocorrelation:.3g}, misfit above "
                f"{AUTOCORRELATION_THRESHOLD:g}: not noise) and "
                f"{self.ratio:.3g} times the noise the data imply"
            )
        if self.worst:
            text += "; worst: " + ", ".join(
                f"{self.channel_name(w, body_names, convention)} ({w.ratio:.3g}x, "
                f"largest at t = {w.time:.6g} s)"
                for w in self.worst
            )
        return text


def second_difference_noise(y: np.ndarray) -> np.ndarray:
    """$\\hat\\sigma^2$ per channel of `y` `(times, ...)` from second differences
    of consecutive measured samples (NaN where fewer than one is available)."""
    d2 = y[2:] - 2 * y[1:-1] + y[:-2]
    with np.errstate(invalid="ignore"):
        return (
            np.nanmean(d2**2, axis=0) / 6.0 if len(d2) else np.full(y.shape[1:], np.nan)
        )


def misfit_check(
    parts, problem, n_fitted: int, threshold: float = MISFIT_THRESHOLD
) -> MisfitCheck:
    """The `MisfitCheck` of the residuals `parts` (per batch, as
    `residuals_by_experiment` returns them, scaled by `problem.scale`) of a fit
    of `n_fitted` unknowns."""
    rtol, atol = float(problem.options.rtol), float(problem.options.atol)
    declared = problem.batches[0].experiments.sigma is not None
    scale = float(problem.scale)
    total, count = 0.0, 0
    lag_sum, lag_norm = 0.0, 0.0  # the pooled lag-1 autocorrelation
    channels = []  # (ratio, experiment, body, coordinate, time)
    row = 0
    for data, part in zip(problem.batches, parts):
        r = np.asarray(part) / scale  # (batch, times, bodies, 6 or 12)
        weight = np.asarray(data.y_weight)
        series = [np.asarray(data.experiments.y)]
        if data.ydot is not None:
            weight = np.concatenate([weight, np.asarray(data.ydot_weight)], axis=-1)
            series.append(np.asarray(data.experiments.ydot))
        measured_values = np.concatenate(series, axis=-1)  # NaN where missing
        measured = weight > 0
        ts = np.asarray(data.experiments.ts)
        for b in range(r.shape[0]):
            rb = np.where(measured[b], r[b], 0.0)
            if not declared:
                y = measured_values[b]
                var = second_difference_noise(y)
                top = np.nanmax(np.abs(y), axis=0)
                floor = (10 * (rtol * top + atol)) ** 2
                var = np.where(np.isfinite(var), np.maximum(var, floor), floor)
                n_c = np.maximum(measured[b].sum(axis=0), 1)
                above = np.sum(rb**2, axis=0) / n_c > floor
                both = measured[b][1:] & measured[b][:-1]
                lagged = np.where(both, rb[1:] * rb[:-1], 0.0)
                lag_sum += float(np.sum(np.where(above, lagged.sum(axis=0), 0.0)))
                lag_norm += float(np.sum(np.where(above, np.sum(rb**2, axis=0), 0.0)))
                rb = rb / np.sqrt(var)
            n = measured[b].sum(axis=0)
            ms = np.where(n > 0, np.sum(rb**2, axis=0) / np.maximum(n, 1), 0.0)
            total += float(np.sum(rb**2))
            count += int(n.sum())
            worst_t = np.argmax(np.abs(rb), axis=0)
            for body in range(rb.shape[1]):
                for c in range(rb.shape[2]):
                    if n[body, c]:
                        channels.append(
                            (
                                float(ms[body, c]),
                                problem.order[row],
                                body,
                                c,
                                float(ts[b, worst_t[body, c]]),
                            )
                        )
            row += 1
    dof = max(count - n_fitted, 1)
    ratio = total / dof if np.isfinite(total) else np.inf
    channels.sort(key=lambda x: -x[0])
    worst = tuple(
        WorstChannel(e, body, c, ratio_c, t)
        for ratio_c, e, body, c, t in channels[:WORST_SHOWN]
    )
    rho = lag_sum / lag_norm if lag_norm > 0 else float("nan")
    return MisfitCheck(
        float(ratio), float(threshold), declared, 0.5 * dof, worst, float(rho)
    )
