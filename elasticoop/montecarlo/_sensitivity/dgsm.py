"""Derivative-based global sensitivity measures from exact derivatives, and their
bound on the total Sobol' indices.

With the derivatives $\\partial y/\\partial x_i$ at samples of the input law
(`local_sensitivities`: forward-mode through the solver), the measure of factor
$i$ is $\\nu_i = \\mathbb E[(\\partial y/\\partial x_i)^2]$. If the law $\\mu_i$ of
$X_i$ satisfies a Poincaré inequality
$\\operatorname{Var}_{\\mu_i}(g) \\le C(\\mu_i)\\,\\mathbb E_{\\mu_i}[g'^2]$, then
(Sobol' and Kucherenko 2009; Lamboni et al. 2013)

$$S_{T,i} \\le \\frac{C(\\mu_i)\\,\\nu_i}{\\operatorname{Var}(Y)}.$$

The constants: uniform on $[a, b]$, $C = (b-a)^2/\\pi^2$; normal (and a normal law
truncated to an interval), $C = \\sigma^2$; a log-normal law has none, so its
factor is measured on $\\log x$ (Sobol' indices do not change under a monotone map
of one factor): $\\partial y/\\partial \\log x = x\\,\\partial y/\\partial x$ and
$C = \\sigma_{\\log}^2$. Other laws get no bound (NaN). The bound and $\\nu_i$ have
percentile bootstrap intervals (`scipy.stats.bootstrap`, samples resampled with
their outputs).
"""

import warnings

import numpy as np
import xarray as xr
from scipy.stats import bootstrap as scipy_bootstrap

from ..._status import Status
from ..distributions import LogNormal, Normal, TruncatedNormal, Uniform
from ..sampling import active_entries
from ..sensitivity import jacobian_name, local_sensitivities
from ..study import Study
from .factors import _label
from .sobol import DEFAULT_BOOTSTRAP, _check_positive, estimator_versions


def poincare_constants(study: Study) -> tuple[np.ndarray, np.ndarray]:
    """For every scalar parameter (flattened as in `sampling.active_entries`): the
    Poincaré constant of its law, in the leaf's units (NaN where unknown), and
    whether it is measured on $\\log x$ (log-normal laws)."""
    constants, logs = [], []
    for p in study.parameters:
        shape = study.leaf_shapes[p.name]
        law = p.distribution
        scale = np.asarray(p.nominal(study.inputs)) if p.relative else np.ones(shape)
        log = np.zeros(shape, bool)
        if isinstance(law, Uniform):
            c = (scale * (np.asarray(law.high) - np.asarray(law.low))) ** 2 / np.pi**2
        elif isinstance(law, Normal | TruncatedNormal):
            c = (scale * np.asarray(law.std)) ** 2
        elif isinstance(law, LogNormal):
            c, log = np.asarray(law.log_std) ** 2, np.ones(shape, bool)
        else:
            c = np.nan
        constants.append(np.broadcast_to(c, shape).ravel())
        logs.append(np.broadcast_to(log, shape).ravel())
    return np.concatenate(constants), np.concatenate(logs)


def dgsm(
    study: Study,
    indices=None,
    outputs=None,
    *,
    bootstrap: int = DEFAULT_BOOTSTRAP,
    confidence: float = 0.95,
    seed: int = 0,
    batch_width: int = 8,
) -> xr.Dataset:
    """$\\nu_i$ and the bound $C_i\\nu_i/\\operatorname{Var}(Y)$ on each total index,
    for every element of the `outputs` (default: all), from the exact derivatives
    at the samples `indices` of `study` (default: all; about $1 + D$ simulations
    each, $D$ the scalar parameters).

    **Returns:** an `xarray.Dataset` with dimension `factor` (the parameters that
    vary), `poincare` (the constants $C_i$), `log_scale` (measured on
    $\\log x$), and per output `y`: `nu_y`, `dgsm_bound_y` with `_low`/`_high`
    interval ends (dims `factor`, the output's own), and `variance_y`, the
    variance of $Y$ over the samples used.
    """
    _check_positive(bootstrap, "bootstrap")
    sens = local_sensitivities(study, indices, batch_width)
    active = active_entries(study)
    constants, logs = poincare_constants(study)
    constants, logs = constants[active], logs[active]
    labels, offset = [], 0
    for p in study.parameters:
        dims = sens[p.name].dims[1:]
        for k, index in enumerate(np.ndindex(study.leaf_shapes[p.name])):
            if active[offset + k]:
                labels.append(_label(sens, p.name, dims, index))
        offset += int(np.prod(study.leaf_shapes[p.name], dtype=int))
    names = list(study.outputs) if outputs is None else list(outputs)
    n = sens.sizes["sample"]
    data: dict[str, tuple] = {
        "poincare": (("factor",), constants),
        "log_scale": (("factor",), logs),
    }
    coords: dict = {"factor": labels}
    for name in names:
        if name not in study.outputs:
            raise ValueError(f"no output {name!r} in the study")
        y = sens[name].values.reshape(n, -1)
        grads = []
        for p in study.parameters:
            jac = sens[jacobian_name(name, p.name)].values.reshape(n, y.shape[1], -1)
            if isinstance(p.distribution, LogNormal):  # d y / d log x
                jac = jac * sens[p.name].values.reshape(n, 1, -1)
            grads.append(jac)
        g = np.concatenate(grads, axis=2)[:, :, active]
        ok = sens["status"].values == Status.SUCCESS
        ok &= np.isfinite(y).all(axis=1) & np.isfinite(g).all(axis=(1, 2))
        g2, yv = g[ok] ** 2, y[ok]
        if ok.sum() < 2:
            raise ValueError("fewer than 2 samples succeeded: no DGSM estimate")
        nu = g2.mean(axis=0).T  # (factor, elements)
        var = yv.var(axis=0, ddof=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            bound = constants[:, None] * nu / var
            low, high = _interval(g2, yv, constants, bootstrap, confidence, seed)
        dims = sens[name].dims[1:]
        shape = sens[name].shape[1:]
        d = len(labels)
        data[f"nu_{name}"] = (("factor", *dims), nu.reshape(d, *shape))
        for key, value in (("", bound), ("_low", low), ("_high", high)):
            value = np.where(var > 0, value, np.nan)
            data[f"dgsm_bound{key}_{name}"] = (
                ("factor", *dims),
                value.reshape(d, *shape),
            )
        data[f"variance_{name}"] = (dims, var.reshape(shape))
        coords |= {k: sens[k].values for k in dims if k in sens.coords}
    return xr.Dataset(
        data,
        coords=coords,
        attrs={
            "method": "dgsm",
            "samples": int(n),
            "bootstrap": int(bootstrap),
            "confidence": float(confidence),
        }
        | estimator_versions(),
    )


def _interval(g2, y, constants, n_resamples, confidence, seed):
    """Percentile bootstrap interval of $C\\nu/\\operatorname{Var}(Y)$, the samples
    resampled with their outputs."""

    def statistic(g2, y, axis):
        nu = np.mean(g2, axis=axis)
        var = np.var(y, axis=axis, ddof=1)
        return constants[:, None] * nu / var  # (elements, factors, resamples)

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # degenerate resamples of a constant factor
        res = scipy_bootstrap(
            (g2, y[..., None]),
            statistic,
            paired=True,
            vectorized=True,
            axis=0,
            n_resamples=n_resamples,
            confidence_level=confidence,
            method="percentile",
            rng=np.random.default_rng(seed),
        )
    return res.confidence_interval.low.T, res.confidence_interval.high.T


def check_dgsm_bounds(indices: xr.Dataset, measures: xr.Dataset) -> xr.Dataset:
    """The bound $S_{T,i} \\le C_i\\nu_i/\\operatorname{Var}(Y)$ checked for every
    output element that both `indices` (of `sobol_indices`) and `measures` (of
    `dgsm`) hold: per output `y`, `ST_y`, `ST_conf_y`, `dgsm_bound_high_y` and
    `bound_holds_y`: 1 where the interval of $S_{T,i}$ reaches below the upper
    end of the bound's interval, 0 where it lies wholly above it (a violation:
    too few samples, or a law whose constant is wrong), NaN where there is no
    bound."""
    if list(indices["factor"].values) != list(measures["factor"].values):
        raise ValueError("the Sobol' indices and the DGSM have different factors")
    data = {}
    for key in indices.data_vars:
        name = str(key)[3:]
        if not str(key).startswith("ST_") or str(key).startswith("ST_conf_"):
            continue
        if f"dgsm_bound_high_{name}" not in measures:
            continue
        st, conf = indices[f"ST_{name}"], indices[f"ST_conf_{name}"]
        high = measures[f"dgsm_bound_high_{name}"]
        holds = xr.where(st - conf <= high, 1.0, 0.0)
        data[f"ST_{name}"] = st
        data[f"ST_conf_{name}"] = conf
        data[f"dgsm_bound_{name}"] = measures[f"dgsm_bound_{name}"]
        data[f"dgsm_bound_high_{name}"] = high
        data[f"bound_holds_{name}"] = holds.where(np.isfinite(high) & np.isfinite(st))
    return xr.Dataset(data, attrs={"method": "dgsm bound check"})
