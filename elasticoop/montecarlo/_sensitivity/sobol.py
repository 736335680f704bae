"""Sobol' indices of a study run with the Saltelli design, with bootstrap
confidence intervals (`SALib.analyze.sobol`).

For an output $Y = f(X_1..X_D)$ of independent factors, the first-order index
$S_i = \\operatorname{Var}(\\mathbb E[Y|X_i]) / \\operatorname{Var}(Y)$ is the share
of the variance that $X_i$ explains alone, the total index
$S_{T,i} = \\mathbb E[\\operatorname{Var}(Y|X_{\\sim i})] / \\operatorname{Var}(Y)$
the share it takes part in, interactions included ($S_{T,i} - S_i$ is the part
through interactions), and the second-order index $S_{ij}$ the share of the
interaction of $X_i$ and $X_j$ alone. From the rows $A$, $AB_i$ (A with column $i$
of B), $BA_i$ and $B$ of each base point, SALib uses Saltelli's (2010) estimator
of $S_i$, Jansen's of $S_{T,i}$ and Saltelli's (2002) of $S_{ij}$; the intervals
are $\\pm z\\,\\hat\\sigma$ with $\\hat\\sigma$ the standard deviation of the index
over bootstrap resamples of the base points.

A base point one of whose rows failed (or gave a non-finite value) is left out of
that output element's estimate; their number is recorded.
"""

import importlib.metadata
import warnings

import numpy as np
import xarray as xr
from scipy.stats import norm

from ..._version import __version__
from ..sampling import rows_per_point
from .factors import (
    Factors,
    element_coords,
    factors_of,
    output_columns,
    output_names,
    study_description,
)

SALTELLI = ("saltelli", "saltelli-second-order")
# Elements of the resampled arrays (points x resamples x output elements) held at
# once.
_CHUNK_ELEMENTS = 4_000_000
DEFAULT_BOOTSTRAP = 1000


def sobol_indices(
    results: xr.Dataset,
    outputs=None,
    *,
    second_order: bool | None = None,
    bootstrap: int = DEFAULT_BOOTSTRAP,
    confidence: float = 0.95,
    seed: int = 0,
    base_samples: int | None = None,
) -> xr.Dataset:
    """First-order, total (and second-order) Sobol' indices of every element of
    the `outputs` (default: all) of a study run with `sampling="saltelli"` or
    `"saltelli-second-order"`.

    **Arguments:**

    - `results`: the dataset of `run_study` or `open_study` (an incomplete store's
      complete base points are used).
    - `second_order`: estimate $S_{ij}$ (default: when the design allows it; for
      outputs without a time axis).
    - `bootstrap`, `confidence`, `seed`: resamples, level and seed of the
      intervals.
    - `base_samples`: use only the first this many base points (convergence).

    **Returns:** an `xarray.Dataset` with dimension `factor` (labels like
    `"stiffness[plate-left, x]"`) and, per output `y`, variables `S1_y`, `ST_y`
    (dims `factor`, the output's own) and their interval half-widths
    `S1_conf_y`, `ST_conf_y` (the interval is the index $\\pm$ this), `S2_y`,
    `S2_conf_y` (dims `factor`, `factor_2`, ...) when asked, and `dropped_y`,
    the base points left out. An element that does not vary has NaN indices.
    """
    factors = factors_of(results)
    design = factors.sampling
    if design not in SALTELLI:
        raise ValueError(
            f"Sobol' indices need the Saltelli design (sampling 'saltelli' or "
            f"'saltelli-second-order'); these results were drawn with {design!r}"
        )
    has_second = design == "saltelli-second-order"
    if second_order is None:
        second_order = has_second
    if second_order and not has_second:
        raise ValueError(
            "second-order indices need sampling='saltelli-second-order'; these "
            "results were drawn with 'saltelli'"
        )
    _check_positive(bootstrap, "bootstrap")
    if not 0 < confidence < 1:
        raise ValueError(f"confidence must be in (0, 1), got {confidence!r}")
    rows = _blocks(results, factors, base_samples)
    d = len(factors)
    first_rows = [0, *range(1, d + 1), rows.shape[1] - 1]
    problem = {"num_vars": d, "names": list(factors.labels), "bounds": [[0, 1]] * d}
    data, coords = {}, {"factor": list(factors.labels)}
    for name in output_names(results, outputs):
        own = element_coords(results, name)
        dims = results[name].dims[1:]
        shape = results[name].shape[1:]
        with_s2 = bool(second_order) and "time" not in dims
        block = rows if with_s2 else rows[:, first_rows]
        y, ok = output_columns(results, name)
        values, usable = y[block], ok[block].all(axis=1)
        estimates = _estimate(
            problem, values, usable, with_s2, bootstrap, confidence, seed
        )
        for key, array in estimates.items():
            if key.startswith("S2"):
                data[f"{key}_{name}"] = (
                    ("factor", "factor_2", *dims),
                    array.reshape(d, d, *shape),
                )
            else:
                data[f"{key}_{name}"] = (("factor", *dims), array.reshape(d, *shape))
        dropped = (~usable).sum(axis=0).reshape(shape)
        data[f"dropped_{name}"] = (dims, dropped)
        coords |= {k: v.values for k, v in own.items()}
    if second_order:
        coords["factor_2"] = list(factors.labels)
    return xr.Dataset(
        data,
        coords=coords,
        attrs={
            "method": "sobol",
            "base_samples": int(rows.shape[0]),
            "runs": int(rows.size),
            "bootstrap": int(bootstrap),
            "confidence": float(confidence),
            "sampling": design,
        }
        | estimator_versions(),
    )


def estimator_versions() -> dict[str, str]:
    """The versions of what estimated a result (its `attrs`, kept in the files
    written from it): SALib, SciPy and elasticoop."""
    return {
        "SALib_version": importlib.metadata.version("SALib"),
        "scipy_version": importlib.metadata.version("scipy"),
        "elasticoop_version": __version__,
    }


def _check_positive(value, name: str) -> None:
    if isinstance(value, bool) or not isinstance(value, int | np.integer) or value < 1:
        raise ValueError(f"{name} must be a positive integer, got {value!r}")


def _blocks(results, factors: Factors, base_samples) -> np.ndarray:
    """Row numbers of the complete base points, shape `(points, rows a point)`,
    checked against the design (row $1+k$ of a point differs from its row $A$ in
    factor $k$ alone)."""
    d = len(factors)
    block = rows_per_point(factors.sampling, d)
    n_study = int(study_description(results)["n_samples"])
    samples = results["sample"].values
    if n_study % block or not np.array_equal(samples, np.arange(samples.size)):
        raise ValueError(
            f"the results do not hold a {factors.sampling!r} design of {d} varying "
            f"factors ({n_study} samples, rows {samples[:1]}..): use all samples "
            f"of a study from their first"
        )
    n_points = samples.size // block
    if base_samples is not None:
        _check_positive(base_samples, "base_samples")
        if base_samples > n_points:
            raise ValueError(
                f"base_samples = {base_samples}, but the results hold {n_points} "
                f"complete base points"
            )
        n_points = base_samples
    if n_points < 2:
        raise ValueError(
            f"the results hold {n_points} complete base point(s) of the design; "
            f"Sobol' indices need at least 2"
        )
    rows = np.arange(n_points * block).reshape(n_points, block)
    x = factors.values
    for k in range(d):
        changed = np.flatnonzero(x[rows[0, 0]] != x[rows[0, k + 1]])
        if changed.tolist() != [k]:
            raise ValueError(
                f"the results' factors do not match the {factors.sampling!r} "
                f"design: row {k + 1} should differ from row 0 in "
                f"{factors.labels[k]!r} alone"
            )
    return rows


def _estimate(problem, values, usable, second_order, bootstrap, confidence, seed):
    """The indices of each output element (columns of `values`, of shape
    `(points, rows, elements)`) by SALib's estimators (`SALib.analyze.sobol`'s
    `first_order`, `total_order`, `second_order`), applied to many elements at
    once, with `SALib.analyze.sobol.analyze`'s normalisation, resampling and
    intervals (the same numbers, element by element: see the tests)."""
    d, m = problem["num_vars"], values.shape[2]
    keys = ["S1", "S1_conf", "ST", "ST_conf"] + (["S2", "S2_conf"] * second_order)
    out = {
        k: np.full((d, d, m) if k.startswith("S2") else (d, m), np.nan) for k in keys
    }
    groups: dict[bytes, list[int]] = {}
    for j in range(m):
        y = values[usable[:, j], :, j]
        if y.shape[0] >= 2 and np.ptp(y) > 0:  # else: no variance to share out
            groups.setdefault(usable[:, j].tobytes(), []).append(j)
    z = norm.ppf(0.5 + confidence / 2)
    for columns in groups.values():
        rows = usable[:, columns[0]]
        n = int(rows.sum())
        r = np.random.default_rng(seed + 1).integers(n, size=(n, bootstrap))
        step = max(1, _CHUNK_ELEMENTS // (n * bootstrap * (2 if second_order else 1)))
        for start in range(0, len(columns), step):
            cols = columns[start : start + step]
            y = values[rows][:, :, cols]
            y = (y - y.mean(axis=(0, 1))) / y.std(axis=(0, 1))
            estimates = _indices(y, r, z, second_order)
            for k, array in estimates.items():
                out[k][..., cols] = array
    return out


def _indices(y, r, z, second_order):
    """SALib's indices and interval half-widths of the columns of `y` (points,
    rows, elements), normalised."""
    from SALib.analyze.sobol import first_order, second_order as s2, total_order

    d = (y.shape[1] - 2) // (2 if second_order else 1)
    a, b = y[:, 0], y[:, -1]
    ab = [y[:, 1 + k] for k in range(d)]
    ba = [y[:, 1 + d + k] for k in range(d)] if second_order else []
    a_r, b_r = a[r], b[r]
    spread = np.ptp(np.concatenate([a_r, b_r]), axis=(0, 1)) != 0
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", UserWarning)  # SALib's constant-output note
        out["S1"] = np.stack([first_order(a, ab[k], b) for k in range(d)])
        out["ST"] = np.stack([total_order(a, ab[k], b) for k in range(d)])
        out["S1_conf"] = np.stack(
            [_half_width(first_order(a_r, ab[k][r], b_r), z, spread) for k in range(d)]
        )
        out["ST_conf"] = np.stack(
            [_half_width(total_order(a_r, ab[k][r], b_r), z, spread) for k in range(d)]
        )
        if second_order:
            shape = (d, d, y.shape[2])
            out["S2"], out["S2_conf"] = np.full(shape, np.nan), np.full(shape, np.nan)
            for j in range(d):
                for k in range(j + 1, d):
                    out["S2"][j, k] = s2(a, ab[j], ab[k], ba[j], b)
                    resampled = s2(a_r, ab[j][r], ab[k][r], ba[j][r], b_r)
                    out["S2_conf"][j, k] = z * resampled.std(axis=0, ddof=1)
    return out


def _half_width(resampled, z, spread):
    return np.where(spread, z * resampled.std(axis=0, ddof=1), 0.0)
