"""A sensitivity ranking from the samples alone: Spearman's rank correlation.

For a scalar output $y$ and each scalar parameter entry $\\theta_j$ that varies
over the study, Spearman's $\\rho_j$ is the Pearson correlation of their ranks over
the valid samples: $+1$ ($-1$) when $y$ rises (falls) monotonically with
$\\theta_j$, near 0 when $\\theta_j$ does not sway $y$. Unlike `variance_ranking` it
needs no further simulation and no linearisation, and it is exact for monotone
dependences; it cannot separate the effects of correlated parameters (the study's
parameters are drawn independently).
"""

import json
import warnings

import numpy as np
import xarray as xr
from scipy.stats import ConstantInputWarning, spearmanr

from .stats import named_variable, valid_samples


def parameter_names(ds: xr.Dataset) -> list[str]:
    """The parameters of a study's results (from the study description)."""
    study = json.loads(ds.attrs.get("study", "{}"))
    return [p["name"] for p in study.get("parameters", [])]


def _entry_label(name: str, x: xr.DataArray, index: tuple[int, ...]) -> str:
    if not index:
        return name
    parts = []
    for dim, k in zip(x.dims[1:], index):
        coord = x.coords.get(dim)
        parts.append(str(coord.values[k]) if coord is not None else str(k))
    return f"{name}[{', '.join(parts)}]"


def rank_correlations(ds: xr.Dataset, output: str, **select) -> xr.DataArray:
    """Spearman's $\\rho$ between output `output` and every scalar parameter entry
    that varies, over the samples valid for the output, sorted by decreasing
    $|\\rho|$.

    **Arguments:**

    - `ds`: a study's results (`run_study`, `open_study`).
    - `output`: the output's name; `select` picks one element of it by index
      (`xarray.Dataset.isel` keywords, e.g. `connection=0`) when it is not scalar.

    **Returns:** a `DataArray` over dimension `parameter` (labels like
    `"stiffness[beam-left, x]"`), with `attrs["n"]`, the number of samples used.
    """
    y = named_variable(ds, output)
    y = y.isel(select) if select else y
    if y.ndim != 1:
        raise ValueError(
            f"output {output!r} is not scalar per sample (dims {y.dims[1:]}); pick "
            f"an element, e.g. rank_correlations(ds, {output!r}, {y.dims[1]}=0)"
        )
    ok = valid_samples(ds, output).values & np.isfinite(y.values)
    if ok.sum() < 3:
        raise ValueError(
            f"fewer than 3 valid samples of {output!r}: cannot rank correlations"
        )
    y_ok = y.values[ok]
    labels, rhos = [], []
    for name in parameter_names(ds):
        x = ds[name]
        values = x.values[ok].reshape(int(ok.sum()), -1)
        shape = x.shape[1:]
        for flat, index in enumerate(np.ndindex(*shape)):
            column = values[:, flat]
            if not np.all(np.isfinite(column)) or np.ptp(column) == 0:
                continue  # a fixed entry: no correlation to speak of
            labels.append(_entry_label(name, x, index))
            rhos.append(_spearman(column, y_ok))
    rho = np.asarray(rhos, dtype=np.float64)
    order = np.argsort(-np.abs(np.nan_to_num(rho)), kind="stable")
    return xr.DataArray(
        rho[order],
        dims=("parameter",),
        coords={"parameter": np.asarray(labels, dtype=str)[order]},
        name=f"rank_correlation_{output}",
        attrs={"n": int(ok.sum())},
    )


def _spearman(a: np.ndarray, b: np.ndarray) -> float:
    """Spearman's rho (`scipy.stats.spearmanr`); NaN when either has no spread
    (e.g. an output that does not change)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ConstantInputWarning)
        return float(spearmanr(a, b).statistic)
