"""`IdentificationResult`: the fitted model, its uncertainty and how the fit went."""

import dataclasses

import numpy as np

from .misfit import AUTOCORRELATION_THRESHOLD, MisfitCheck
from .uncertainty import Uncertainty


@dataclasses.dataclass(frozen=True)
class ParameterRow:
    """One row of the parameter table (physical units)."""

    name: str
    estimate: float
    stderr: float
    initial: float
    start: float
    identifiable: bool
    held: bool = False

    @property
    def relative_stderr(self) -> float:
        return self.stderr / abs(self.estimate) if self.estimate != 0 else np.inf


@dataclasses.dataclass(frozen=True)
class IdentificationResult:
    """The outcome of `identify`.

    **Fields:**

    - `model`: the fitted model.
    - `stderr`: standard errors, in the structure of `where(model)` (inf for a
      parameter the data cannot determine).
    - `loss_history`: loss $\\tfrac12\\sum r^2$ after each accepted iteration.
    - `converged`: whether the convergence test was met after the loss decreased.
    - `status`: `"converged"`, `"max_iterations"`, `"misfit"` (the model does
      not explain the data, see `misfit`), `"stalled"` (no further progress, or
      no step lowered the loss from the start) or `"failed"` (every trial step's
      simulation failed, or the solver failed); `reason` says why in words,
      including how many trial simulations failed and why.
    - `names`, `estimate`, `initial`, `start`: the free parameters' names, fitted
      values, values the optimiser started from, and values in the model passed in.
    - `uncertainty`: Fisher information, covariance, correlations, singular
      directions and the per-parameter `identifiable` flags (NaN, with
      `uncertainty.reason` saying why, where they could not be computed).
    - `n_iterations`, `n_simulations`, `n_rejected`, `n_failed_trials`: accepted
      iterations, simulations of single experiments (a simulation carrying
      forward-mode sensitivities or followed by a reverse-mode pass counts once),
      rejected trial steps, and trial steps whose simulation failed.
    - `method`, `wall_time` [s] (fit only, including compilation), `notes`.
    - `held`: per parameter, whether it was held at its start because the data
      do not determine it (`identify(hold_unidentifiable=True)`); its `estimate`
      is then its value in the model passed in (`start`; `initial` where that is
      outside the transform's range), and its standard error the one it had when
      found not identifiable.
    - `initial_states`: per experiment, the initial state `(y_init, ydot_init)`
      (each `(bodies, 6)`) the fitted simulations start from: estimated where
      `identify(fit_initial=...)` says so, the experiment's own otherwise.
    - `initial_state_names`, `initial_state_estimate`, `initial_state_stderr`:
      the estimated initial-state entries (empty when none were estimated),
      e.g. `experiment[0].ydot_init.contact1.z`, their values and standard errors
      (marginal over the parameters not held).
    - `misfit`: the residuals against the noise (`MisfitCheck`; `None` for a
      failed fit). Where `misfit.misfit`, `status` is `"misfit"` and the standard
      errors are not meaningful.
    """

    model: object
    stderr: object
    loss_history: np.ndarray
    converged: bool
    status: str
    reason: str
    names: tuple
    estimate: np.ndarray
    initial: np.ndarray
    start: np.ndarray
    uncertainty: Uncertainty
    n_iterations: int
    n_simulations: int
    n_rejected: int
    n_failed_trials: int
    method: str
    wall_time: float
    notes: tuple = ()
    held: np.ndarray | None = None
    initial_states: tuple = ()
    initial_state_names: tuple = ()
    initial_state_estimate: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(0)
    )
    initial_state_stderr: np.ndarray = dataclasses.field(
        default_factory=lambda: np.zeros(0)
    )
    misfit: MisfitCheck | None = None

    @property
    def stderr_meaningful(self) -> bool:
        """Whether the standard errors mean anything: computed, at a fit that
        explains the data (not a misfit or a failed fit)."""
        return self.status not in ("misfit", "failed") and not self.uncertainty.reason

    @property
    def held_mask(self) -> np.ndarray:
        """`held` as a boolean array (all false when not given)."""
        if self.held is None:
            return np.zeros(len(self.names), dtype=bool)
        return np.asarray(self.held, dtype=bool)

    @property
    def identifiable(self) -> np.ndarray:
        return self.uncertainty.identifiable

    @property
    def correlation(self) -> np.ndarray:
        return self.uncertainty.correlation

    @property
    def table(self) -> list[ParameterRow]:
        """One `ParameterRow` per free parameter."""
        return [
            ParameterRow(
                name=n,
                estimate=float(p),
                stderr=float(s),
                initial=float(i),
                start=float(s0),
                identifiable=bool(ok),
                held=bool(h),
            )
            for n, p, s, i, s0, ok, h in zip(
                self.names,
                self.estimate,
                self.uncertainty.stderr,
                self.initial,
                self.start,
                self.identifiable,
                self.held_mask,
            )
        ]

    def report(self, max_correlation: float = 0.95) -> str:
        """A text report: how the fit ended, then a table of estimate, standard
        error, relative standard error and initial value per parameter, flagged
        parameters (and whether they were held at their start), strongly
        correlated pairs (|corr| > `max_correlation`), and the estimated initial
        states."""
        lines = [
            f"identify: {self.status} ({self.reason})",
            f"  method {self.method}; {self.n_iterations} iterations, "
            f"{self.n_simulations} simulations, {self.n_rejected} rejected steps "
            f"({self.n_failed_trials} failed simulations), {self.wall_time:.1f} s",
            f"  loss {self.loss_history[0]:.6g} -> {self.loss_history[-1]:.6g}, "
            f"noise scale {self.uncertainty.noise_scale:.3g}",
        ]
        if self.misfit is not None:
            m = self.misfit
            if m.declared:
                lines.append(
                    f"  residuals {m.ratio:.3g} x the declared noise (mean square per "
                    f"degree of freedom; 1 at the noise floor, misfit above "
                    f"{m.threshold:g}); noise floor of the loss {m.noise_floor:.6g}"
                )
            else:
                lines.append(
                    f"  residuals {m.ratio:.3g} x the noise the data imply; lag-1 "
                    f"autocorrelation {m.autocorrelation:.3g} (noise: about 0; "
                    f"misfit above {AUTOCORRELATION_THRESHOLD:g})"
                )
        if not self.stderr_meaningful:
            lines.append(
                "  STANDARD ERRORS NOT MEANINGFUL: "
                + (
                    "the model does not explain the data"
                    if self.status == "misfit"
                    else "the fit failed"
                    if self.status == "failed"
                    else "they could not be computed"
                )
            )
        lines += [f"  note: {n}" for n in self.notes]
        if self.uncertainty.reason:
            lines.append(f"  {self.uncertainty.reason}")
        width = max(len("parameter"), *(len(n) for n in self.names))
        lines.append(
            f"  {'parameter':<{width}}  {'estimate':>12}  {'std. error':>11}  "
            f"{'rel.':>8}  {'initial':>12}  std. error"
        )
        any_held = bool(np.any(self.held_mask))
        for row in self.table:
            known = not self.uncertainty.reason
            flag = "" if row.identifiable or not known else ", NOT IDENTIFIABLE"
            basis = "conditional on the held values" if any_held else "marginal"
            if row.held:
                basis = "held at its start value (not fitted)"
                flag = ", NOT IDENTIFIABLE"
            lines.append(
                f"  {row.name:<{width}}  {row.estimate:12.6g}  {row.stderr:11.4g}  "
                f"{_relative(row.relative_stderr):>8}  {row.initial:12.6g}  "
                f"{basis}{flag}"
            )
        corr = self.correlation
        pairs = [
            (i, j)
            for i in range(len(self.names))
            for j in range(i + 1, len(self.names))
            if np.isfinite(corr[i, j]) and abs(corr[i, j]) > max_correlation
        ]
        if pairs:
            lines.append(f"  correlations above {max_correlation}:")
            lines += [
                f"    {self.names[i]} ~ {self.names[j]}: {corr[i, j]:+.3f}"
                for i, j in pairs
            ]
        n_bad = int(np.sum(~self.identifiable))
        n_held = int(np.sum(self.held_mask))
        if n_bad and not self.uncertainty.reason:
            lines.append(
                f"  {n_bad} parameter(s) not identifiable from these experiments "
                f"(null or poorly determined directions of the Fisher information)"
            )
        if n_held:
            lines.append(
                f"  {n_held} of them held at their start values (not fitted; the "
                f"others are fitted with these values taken as known, so their "
                f"standard errors leave out the held values' uncertainty)"
            )
        if len(self.initial_state_names):
            width = max(len(n) for n in self.initial_state_names)
            lines.append(
                f"  initial state estimated with the parameters "
                f"({len(self.initial_state_names)} entries):"
            )
            lines.append(
                f"    {'entry':<{width}}  {'estimate':>12}  {'std. error':>11}"
            )
            lines += [
                f"    {n:<{width}}  {v:12.6g}  {e:11.4g}"
                for n, v, e in zip(
                    self.initial_state_names,
                    self.initial_state_estimate,
                    self.initial_state_stderr,
                )
            ]
        return "\n".join(lines)

    def __str__(self) -> str:
        return self.report()


def _relative(value: float) -> str:
    """A relative standard error as a percentage; beyond 100x (an estimate near
    zero against its error) a bound, not a meaningless figure."""
    if not np.isfinite(value):
        return "inf"
    if value > 100:
        return ">10000%"
    return f"{value:.2%}"
