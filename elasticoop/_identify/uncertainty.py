"""Uncertainty and identifiability from the Gauss-Newton (Fisher) information.

With whitened residuals $r$ (divided by the noise level $\\sigma$) and their
Jacobian $J_p = \\partial r/\\partial p$ at the optimum, the Fisher information of
the parameters is $\\mathcal I = J_p^T J_p / s^2$, where $s^2 = 1$ when the noise
levels were given and $s^2 = |r|^2/(N - n_p)$ (estimated) otherwise. The
covariance of the estimates is approximately $\\mathcal I^{-1}$.

Identifiability is judged in relative coordinates $q_k = \\delta p_k / |p_k|$
(scale-free): $J_q = J_p\\,\\operatorname{diag}|p|$ has singular values $S_i$ and
right singular vectors $v_i$; along $v_i$ the relative standard error is
$s / S_i$. A direction is *not identifiable* when $S_i \\le$ `rcond` $S_{\\max}$
(numerically null: the data do not depend on it) and *poorly determined* when its
relative standard error exceeds `max_relative_stderr`. A parameter is flagged
when more than `NULL_SHARE` of it lies in the null directions (its standard error
is then infinite), or when its own relative standard error exceeds
`max_relative_stderr`.

When other unknowns were estimated with $p$ (nuisance parameters $x$, e.g. the
experiments' initial states, with Jacobian $J_x$), the uncertainty of $p$ is the
marginal one: $J_p$ is replaced by $(I - P_x) J_p$, $P_x$ the orthogonal projector
onto the columns of $J_x$. Then $J_p^T (I - P_x) J_p$ is the Schur complement of
the $x$ block in the joint information, whose inverse is the $p$ block of the joint
covariance; a parameter whose effect the nuisance parameters can mimic is not
identifiable. The residual degrees of freedom are $N - n_p - n_x$.

Where this cannot be computed (non-finite residuals, Jacobian or estimates, or a
failed decomposition), every quantity is NaN and `Uncertainty.reason` says why.
"""

import dataclasses
import numbers
import warnings

import numpy as np

# Share of a parameter's unit vector in the null space above which it is flagged.
NULL_SHARE = 1e-4


@dataclasses.dataclass(frozen=True)
class Uncertainty:
    """Standard errors, correlations and identifiability of the estimates.

    - `stderr`: standard error of each parameter (physical units; inf where not
      identifiable).
    - `covariance`, `correlation`: `(n_p, n_p)` over the identifiable
      subspace (NaN rows/columns for parameters in a null direction).
    - `fisher`: the Fisher information $J_p^T J_p / s^2$ (physical units; with
      nuisance parameters, the marginal one $J_p^T (I - P_x) J_p / s^2$).
    - `singular_values`, `directions`: $S_i / s$ and $v_i$ (columns) of the
      relative Jacobian; `relative_stderr_directions` $= s/S_i$.
    - `identifiable`: per-parameter flag; `noise_scale`: $s$.
    - `reason`: empty when the uncertainty was computed; otherwise why it could
      not be (all the fields above are then NaN, `identifiable` False).
    """

    stderr: np.ndarray
    covariance: np.ndarray
    correlation: np.ndarray
    fisher: np.ndarray
    singular_values: np.ndarray
    directions: np.ndarray
    identifiable: np.ndarray
    noise_scale: float
    reason: str = ""

    @property
    def relative_stderr_directions(self) -> np.ndarray:
        with np.errstate(divide="ignore"):
            return 1.0 / self.singular_values


def gauss_newton_uncertainty(
    residual,
    jacobian_p,
    p,
    noise_known: bool,
    rcond: float = 1e-8,
    max_relative_stderr: float = 0.5,
    names=None,
    nuisance=None,
) -> Uncertainty:
    """Uncertainty of the estimates $p$ from whitened residuals and their Jacobian.

    **Arguments:**

    - `residual`: $r$ at the optimum, shape `(N,)` (zeros where data are missing).
    - `jacobian_p`: $J_p = \\partial r/\\partial p$, shape `(N, n_p)`.
    - `p`: the estimates, shape `(n_p,)`.
    - `noise_known`: whether $r$ was divided by known noise levels ($s = 1$).
    - `rcond`: singular values below `rcond` times the largest are null directions.
    - `max_relative_stderr`: parameters with a larger relative standard error are
      flagged as not identifiable from these data.
    - `names`: the parameters' names, for messages (default `p[k]`).
    - `nuisance`: $J_x = \\partial r/\\partial x$, shape `(N, n_x)`, of other unknowns
      estimated together with $p$; the uncertainty of $p$ is then marginal over
      them (see the module docstring). `None`: there are none.

    Non-finite inputs, or a singular value decomposition that fails, give an
    `Uncertainty` of NaN whose `reason` says why, with a `RuntimeWarning`.
    """
    check_identifiability_thresholds(rcond, max_relative_stderr)
    residual = np.asarray(residual, dtype=np.float64)
    J = np.asarray(jacobian_p, dtype=np.float64)
    p = np.asarray(p, dtype=np.float64)
    n_res, n_p = J.shape
    names = [f"p[{k}]" for k in range(n_p)] if names is None else list(names)
    Jx = np.zeros((n_res, 0)) if nuisance is None else np.asarray(nuisance, float)
    reason = _non_finite(residual, J, p, names)
    if not reason and not np.all(np.isfinite(Jx)):
        reason = "the Jacobian has non-finite entries for the nuisance parameters"
    if reason:
        return _unavailable(n_p, reason)
    used = np.count_nonzero(
        np.any(J != 0, axis=1) | np.any(Jx != 0, axis=1) | (residual != 0)
    )
    J = project_out(J, Jx, rcond)
    if noise_known:
        s = 1.0
    else:
        dof = max(used - n_p - Jx.shape[1], 1)
        s = _norm(residual) / np.sqrt(dof)
        s = max(s, np.finfo(np.float64).tiny)
    scale = np.where(p != 0, np.abs(p), 1.0)
    Jq = J * scale[None, :]
    try:
        _, S, Vt = np.linalg.svd(Jq, full_matrices=False)
    except np.linalg.LinAlgError as error:
        return _unavailable(
            n_p, f"the singular value decomposition of the Jacobian failed: {error}"
        )
    V = Vt.T
    top = S[0] if S.size else 0.0
    null = S <= rcond * top
    null_share = np.sum(V[:, null] ** 2, axis=1)
    in_null = null_share > NULL_SHARE
    keep = ~null
    # cov_q = s^2 W W^T with W = V_keep diag(1/S_keep); W is scaled to a largest
    # entry of 1 first, so that neither the standard errors nor the correlations
    # over- or underflow for extreme S (e.g. sigma far below the noise)
    W = V[:, keep] / S[keep][None, :]
    size = float(np.max(np.abs(W))) if W.size else 0.0
    unit = W / size if size > 0 else W
    unit_cov = unit @ unit.T
    unit_stderr = np.sqrt(np.diag(unit_cov))
    stderr = s * size * unit_stderr * scale
    with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
        corr = unit_cov / np.outer(unit_stderr, unit_stderr)
        cov = corr * np.outer(stderr, stderr)
    stderr[in_null] = np.inf
    corr[in_null, :] = np.nan
    corr[:, in_null] = np.nan
    cov[in_null, :] = np.nan
    cov[:, in_null] = np.nan
    relative = stderr / scale
    identifiable = (~in_null) & (relative <= max_relative_stderr)
    return Uncertainty(
        stderr=stderr,
        covariance=cov,
        correlation=corr,
        fisher=(J.T @ J) / s**2,
        singular_values=S / s,
        directions=V,
        identifiable=identifiable,
        noise_scale=s,
    )


def check_identifiability_thresholds(rcond, max_relative_stderr) -> None:
    """`rcond` in [0, 1) and `max_relative_stderr` > 0, or a `ValueError` naming
    them (NaN or a negative value silently flagged every parameter, or none)."""
    if not (_real_scalar(rcond) and 0 <= float(rcond) < 1):
        raise ValueError(f"rcond must be a number in [0, 1), got {rcond!r}")
    if not (_real_scalar(max_relative_stderr) and float(max_relative_stderr) > 0):
        raise ValueError(
            f"max_relative_stderr must be a number > 0, got {max_relative_stderr!r}"
        )


def _real_scalar(x) -> bool:
    """A real number: a Python or NumPy one, or a 0-d array of one."""
    if isinstance(x, bool):
        return False
    if isinstance(x, numbers.Real):
        return True
    try:
        arr = np.asarray(x)
    except (TypeError, ValueError):
        return False
    return arr.ndim == 0 and arr.dtype.kind in "iuf"


def project_out(J, nuisance, rcond: float = 1e-8):
    """$(I - P_x) J$: the columns of `J` less their least-squares fit by the columns
    of `nuisance` ($P_x$ the orthogonal projector onto them; singular values below
    `rcond` times the largest are dropped). The nuisance columns are scaled to unit
    norm first, so that their units do not matter."""
    if nuisance.shape[1] == 0:
        return J
    norms = np.sqrt(np.sum(nuisance**2, axis=0))
    A = nuisance / np.where(norms > 0, norms, 1.0)[None, :]
    coef, *_ = np.linalg.lstsq(A, J, rcond=rcond)
    return J - A @ coef


def _norm(x) -> float:
    """$|x|$ without overflow or underflow of the squares."""
    size = float(np.max(np.abs(x))) if x.size else 0.0
    return size * float(np.sqrt(np.sum((x / size) ** 2))) if size > 0 else 0.0


def _non_finite(residual, J, p, names) -> str:
    """Why the inputs cannot give an uncertainty ("" when they can)."""
    problems = []
    bad = [n for n, x in zip(names, p) if not np.isfinite(x)]
    if bad:
        problems.append(f"the estimates of {', '.join(bad)} are not finite")
    bad = [n for n, column in zip(names, J.T) if not np.all(np.isfinite(column))]
    if bad:
        problems.append(f"the Jacobian has non-finite entries for {', '.join(bad)}")
    if not np.all(np.isfinite(residual)):
        problems.append(
            f"{int(np.sum(~np.isfinite(residual)))} residuals are not finite"
        )
    return "; ".join(problems)


def _unavailable(n_p: int, reason: str) -> Uncertainty:
    """An `Uncertainty` of NaN that says why, announced by a `RuntimeWarning`."""
    reason = f"uncertainty not computed: {reason}"
    warnings.warn(
        f"{reason}; its standard errors are NaN", RuntimeWarning, stacklevel=3
    )
    vector, matrix = np.full(n_p, np.nan), np.full((n_p, n_p), np.nan)
    return Uncertainty(
        stderr=vector,
        covariance=matrix,
        correlation=matrix.copy(),
        fisher=matrix.copy(),
        singular_values=vector.copy(),
        directions=matrix.copy(),
        identifiable=np.zeros(n_p, dtype=bool),
        noise_scale=np.nan,
        reason=reason,
    )


def with_held_stderr(
    unc: Uncertainty, held: np.ndarray, held_stderr: np.ndarray
) -> Uncertainty:
    """The `Uncertainty` of the parameters not held (`unc`, over `~held`) spread
    over all parameters: a held parameter (fixed at its start, not fitted) is not
    identifiable, keeps the standard error `held_stderr` it had when it was found
    not identifiable (the reason it was held), and has no covariance, correlation
    or Fisher information (NaN); `directions` get zero rows for it, while
    `singular_values` stay those of the parameters not held."""
    held = np.asarray(held, dtype=bool)
    free = ~held
    n_p = held.size

    def vector(values, fill):
        out = np.full(n_p, fill, dtype=np.asarray(values).dtype)
        out[free] = values
        return out

    def matrix(values):
        out = np.full((n_p, n_p), np.nan)
        out[np.ix_(free, free)] = values
        return out

    stderr = vector(unc.stderr, np.nan)
    stderr[held] = held_stderr[held]
    directions = np.zeros((n_p, unc.directions.shape[1]))
    directions[free] = unc.directions
    return dataclasses.replace(
        unc,
        stderr=stderr,
        covariance=matrix(unc.covariance),
        correlation=matrix(unc.correlation),
        fisher=matrix(unc.fisher),
        directions=directions,
        identifiable=vector(unc.identifiable, False),
    )
