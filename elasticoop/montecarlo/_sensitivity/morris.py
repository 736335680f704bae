"""Morris elementary effects of a study run with the Morris design
(`SALib.analyze.morris`): cheap screening, $r(D+1)$ runs for $r$ trajectories.

Along a trajectory each factor moves once by $\\Delta = L/(2(L-1))$ of its range
in probability ($L$ = `sampling.MORRIS_LEVELS` levels, factors measured by their
CDF $u = F(x)$), and its elementary effect is $(y' - y)/\\Delta$. Over the
trajectories, $\\mu^*$ (the mean absolute effect) ranks the factors' influence and
$\\sigma$ (the effects' standard deviation) flags non-linear or interacting
factors; $\\mu^*$ has a bootstrap interval.
"""

import warnings

import numpy as np
import xarray as xr

from ..sampling import MORRIS_LEVELS, morris_grid, rows_per_point
from .factors import element_coords, factors_of, output_columns, output_names
from .sobol import DEFAULT_BOOTSTRAP, _check_positive, estimator_versions


def morris_effects(
    results: xr.Dataset,
    outputs=None,
    *,
    bootstrap: int = DEFAULT_BOOTSTRAP,
    confidence: float = 0.95,
    seed: int = 0,
) -> xr.Dataset:
    """$\\mu$, $\\mu^*$ (with its interval half-width) and $\\sigma$ of the elementary
    effects of every factor on every element of the `outputs` (default: all) of a
    study run with `sampling="morris"`.

    **Returns:** an `xarray.Dataset` with dimension `factor` and, per output `y`,
    variables `mu_y`, `mu_star_y`, `mu_star_conf_y`, `sigma_y` (dims `factor`
    and the output's own) and `dropped_y` (trajectories left out: one of their
    runs failed).
    """
    from SALib.analyze import morris

    factors = factors_of(results)
    if factors.sampling != "morris":
        raise ValueError(
            f"Morris elementary effects need sampling='morris'; these results were "
            f"drawn with {factors.sampling!r}"
        )
    _check_positive(bootstrap, "bootstrap")
    d = len(factors)
    block = rows_per_point("morris", d)
    n_traj = results.sizes["sample"] // block
    if n_traj < 2:
        raise ValueError(f"the results hold {n_traj} trajectory; Morris needs 2")
    grid = morris_grid(factors.key, d, n_traj)
    moved = np.diff(grid.reshape(n_traj, block, d), axis=1) != 0
    changed = np.diff(
        factors.values[: n_traj * block].reshape(n_traj, block, d), axis=1
    )
    if not np.array_equal(moved, changed != 0):
        raise ValueError(
            "the results' factors do not match the 'morris' design drawn with the "
            "study's key"
        )
    problem = {"num_vars": d, "names": list(factors.labels), "bounds": [[0, 1]] * d}
    keys = ("mu", "mu_star", "mu_star_conf", "sigma")
    data, coords = {}, {"factor": list(factors.labels)}
    for name in output_names(results, outputs):
        dims, shape = results[name].dims[1:], results[name].shape[1:]
        y, ok = output_columns(results, name)
        y = y[: n_traj * block].reshape(n_traj, block, -1)
        usable = np.asarray(ok[: n_traj * block].reshape(n_traj, block, -1).all(axis=1))
        out = {k: np.full((d, y.shape[2]), np.nan) for k in keys}
        for j in range(y.shape[2]):
            keep = usable[:, j]
            if keep.sum() < 2 or not np.ptp(y[keep, :, j]) > 0:
                continue
            x = grid.reshape(n_traj, block, d)[keep].reshape(-1, d)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                res = morris.analyze(
                    problem,
                    x,
                    y[keep, :, j].ravel(),
                    num_resamples=bootstrap,
                    conf_level=confidence,
                    num_levels=MORRIS_LEVELS,
                    seed=seed + 1,
                )
            for k in keys:
                out[k][:, j] = np.asarray(res[k], dtype=np.float64)
        for k, array in out.items():
            data[f"{k}_{name}"] = (("factor", *dims), array.reshape(d, *shape))
        data[f"dropped_{name}"] = (dims, (~usable).sum(axis=0).reshape(shape))
        coords |= {k: v.values for k, v in element_coords(results, name).items()}
    return xr.Dataset(
        data,
        coords=coords,
        attrs={
            "method": "morris",
            "trajectories": int(n_traj),
            "runs": int(n_traj * block),
            "bootstrap": int(bootstrap),
            "confidence": float(confidence),
            "sampling": "morris",
        }
        | estimator_versions(),
    )
