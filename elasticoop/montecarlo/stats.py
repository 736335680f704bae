"""Summary statistics of a study over its successful samples.

A sample counts when its `status` is `Status.SUCCESS` and the variable is finite
everywhere for it; the others are reported by `summary`, never silently averaged.
"""

from statistics import NormalDist

import numpy as np
import xarray as xr

from .._status import Status
from .study import INVALID_SAMPLE


def _status_name(code: int) -> str:
    if code == INVALID_SAMPLE:
        return "INVALID_SAMPLE"
    return Status(code).name


def named_variable(ds: xr.Dataset, name: str) -> xr.DataArray:
    if name not in ds.data_vars:
        raise ValueError(
            f"the study has no variable {name!r}; it has {list(ds.data_vars)}"
        )
    return ds[name]


def valid_samples(ds: xr.Dataset, name: str) -> xr.DataArray:
    """Boolean mask over `sample`: succeeded and `name` finite everywhere."""
    x = named_variable(ds, name)
    other = [str(d) for d in x.dims if d != "sample"]
    finite = x.copy(data=np.isfinite(x.values))
    if other:
        finite = finite.all(other)
    return (ds["status"] == Status.SUCCESS) & finite


def summary(ds: xr.Dataset) -> dict:
    """Counts of samples: total, succeeded, failed by status, and succeeded samples
    with a non-finite output."""
    status = ds["status"].values
    codes, counts = np.unique(status[status != Status.SUCCESS], return_counts=True)
    succeeded = status == Status.SUCCESS
    nonfinite = np.zeros_like(succeeded)
    for name, x in ds.data_vars.items():
        if name in ("status", "event_time"):
            continue
        axes = tuple(range(1, x.ndim))
        nonfinite |= (
            ~np.all(np.isfinite(x.values), axis=axes)
            if axes
            else ~np.isfinite(x.values)
        )
    return {
        "n_samples": int(status.size),
        "n_succeeded": int(succeeded.sum()),
        "n_failed": int((~succeeded).sum()),
        "failures": {_status_name(int(c)): int(n) for c, n in zip(codes, counts)},
        "n_nonfinite": int((succeeded & nonfinite).sum()),
    }


def statistics(ds: xr.Dataset, name: str, quantiles=(0.05, 0.5, 0.95)) -> xr.Dataset:
    """Mean, standard deviation (with Bessel's correction) and quantiles of
    variable `name` over the valid samples, elementwise (e.g. over time).

    **Returns:** an `xarray.Dataset` with `mean`, `std`, `quantiles` (dimension
    `quantile` first) and `n` (number of valid samples).
    """
    q = np.asarray(quantiles, dtype=np.float64)
    if q.ndim != 1 or np.any((q < 0) | (q > 1)):
        raise ValueError(f"quantiles must be numbers in [0, 1], got {quantiles!r}")
    x = named_variable(ds, name)
    ok = valid_samples(ds, name)
    values = x.values[ok.values]
    n = values.shape[0]
    if n == 0:
        raise ValueError(f"no valid sample of {name!r}: see summary(ds)")
    dims = [d for d in x.dims if d != "sample"]
    coords = {d: x.coords[d] for d in dims if d in x.coords}
    std = values.std(axis=0, ddof=1) if n > 1 else np.full(values.shape[1:], np.nan)
    return xr.Dataset(
        {
            "mean": (dims, values.mean(axis=0)),
            "std": (dims, std),
            "quantiles": (["quantile", *dims], np.quantile(values, q, axis=0)),
            "n": n,
        },
        coords=coords | {"quantile": q},
    )


def wilson_interval(successes, n, confidence: float = 0.95):
    """Wilson score interval of a binomial proportion $\\hat p = k/n$:

    $$\\frac{\\hat p + z^2/2n}{1 + z^2/n} \\pm \\frac{z}{1 + z^2/n}
    \\sqrt{\\frac{\\hat p(1 - \\hat p)}{n} + \\frac{z^2}{4n^2}},$$

    $z = \\Phi^{-1}(1 - \\alpha/2)$ (Wilson, JASA 22, 1927). It stays inside $[0, 1]$
    and is informative even when $k = 0$.
    """
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    k = np.asarray(successes, dtype=np.float64)
    n = np.asarray(n, dtype=np.float64)
    if not np.all((n >= 1) & (k >= 0) & (k <= n)):
        raise ValueError(
            f"wilson_interval needs 0 <= successes <= n and n >= 1, got successes = "
            f"{successes!r}, n = {n.tolist()!r}"
        )
    z = NormalDist().inv_cdf(0.5 + confidence / 2)
    p = k / n
    denom = 1 + z**2 / n
    centre = (p + z**2 / (2 * n)) / denom
    half = z / denom * np.sqrt(p * (1 - p) / n + z**2 / (4 * n**2))
    # exact ends: k = 0 gives lower = 0 and k = n upper = 1 (rounding aside)
    lower = np.where(k == 0, 0.0, np.maximum(centre - half, 0.0))
    upper = np.where(k == n, 1.0, np.minimum(centre + half, 1.0))
    return lower, upper


def exceedance_probability(
    ds: xr.Dataset,
    name: str,
    threshold,
    confidence: float = 0.95,
    failures: str = "exclude",
) -> xr.Dataset:
    """$P(x > \\text{threshold})$ of variable `name`, elementwise, with a Wilson
    confidence interval.

    **Arguments:**

    - `threshold`: a number or an array broadcasting to the variable's per-sample
      shape.
    - `confidence`: level of the interval (default 95 %).
    - `failures`: `"exclude"` (default: only valid samples count) or `"exceed"`
      (a failed sample counts as an exceedance: a conservative bound).

    **Returns:** an `xarray.Dataset` with `probability`, `lower`, `upper`, `n`.
    """
    if failures not in ("exclude", "exceed"):
        raise ValueError(f"failures must be 'exclude' or 'exceed', got {failures!r}")
    x = named_variable(ds, name)
    ok = valid_samples(ds, name).values
    dims = [d for d in x.dims if d != "sample"]
    level = np.asarray(threshold, dtype=np.float64)
    if np.any(np.isnan(level)):
        raise ValueError(f"threshold must not be NaN, got {threshold!r}")
    try:
        fits = np.broadcast_shapes(level.shape, x.shape[1:]) == x.shape[1:]
    except ValueError:
        fits = False
    if not fits:
        raise ValueError(
            f"threshold of shape {level.shape} does not broadcast to the shape "
            f"{x.shape[1:]} of {name!r} per sample (dims {dims})"
        )
    exceed = np.asarray(x.values > level)
    if failures == "exclude":
        k, n = exceed[ok].sum(axis=0), int(ok.sum())
    else:
        k, n = exceed[ok].sum(axis=0) + int((~ok).sum()), int(ok.size)
    if n == 0:
        raise ValueError(f"no valid sample of {name!r}: see summary(ds)")
    lower, upper = wilson_interval(k, n, confidence)
    coords = {d: x.coords[d] for d in dims if d in x.coords}
    return xr.Dataset(
        {
            "probability": (dims, k / n),
            "lower": (dims, lower),
            "upper": (dims, upper),
            "n": n,
        },
        coords=coords,
        attrs={"threshold": str(threshold), "confidence": confidence},
    )
