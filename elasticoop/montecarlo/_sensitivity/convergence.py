"""Sobol' indices against the number of base points: does the study have enough?

The Saltelli design's rows come in order of their base points, and any prefix of
$2^k$ scrambled Sobol' points is itself a balanced design, so the indices of the
first $N_k = 2^k$ points are those of a study of that size. As $N$ grows, the
estimates settle and their intervals narrow like $N^{-1/2}$ (or faster); a study is
large enough when the interval half-widths are small against the differences
between the indices that matter.
"""

import numpy as np
import xarray as xr

from ..sampling import rows_per_point
from .factors import factors_of, output_names
from .sobol import DEFAULT_BOOTSTRAP, sobol_indices

SMALLEST = 8  # base points of the first step


def sobol_convergence(
    results: xr.Dataset,
    outputs=None,
    *,
    base_samples=None,
    bootstrap: int = DEFAULT_BOOTSTRAP,
    confidence: float = 0.95,
    seed: int = 0,
) -> xr.Dataset:
    """`sobol_indices` (first and total) of the first $N$ base points of `results`,
    for each $N$ of `base_samples` (default: the powers of two from 8 up to the
    base points held, and that number itself), stacked along a dimension
    `base_samples` (with a coordinate `runs`, the model runs they use)."""
    factors = factors_of(results)
    block = rows_per_point(factors.sampling, len(factors))
    held = results.sizes["sample"] // block
    if base_samples is None:
        base_samples = [2**k for k in range(3, 40) if SMALLEST <= 2**k < held]
        base_samples.append(held)
    steps = [
        sobol_indices(
            results,
            output_names(results, outputs),
            second_order=False,
            bootstrap=bootstrap,
            confidence=confidence,
            seed=seed,
            base_samples=int(n),
        )
        for n in base_samples
    ]
    runs_per_point = rows_per_point("saltelli", len(factors))
    ds = xr.concat(steps, dim="base_samples", combine_attrs="drop_conflicts")
    ds = ds.assign_coords(
        base_samples=np.asarray(base_samples),
        runs=("base_samples", np.asarray(base_samples) * runs_per_point),
    )
    ds.attrs["method"] = "sobol convergence"
    return ds


def convergence_table(convergence: xr.Dataset) -> list[dict]:
    """One row per output element and number of base points: the largest
    interval half-width of $S_i$ and of $S_{T,i}$ over the factors, and the factor
    of the largest $S_{T,i}$ with its value."""
    rows = []
    for key in convergence.data_vars:
        key = str(key)
        if not key.startswith("ST_") or key.startswith("ST_conf_"):
            continue
        name = key[3:]
        st = convergence[key]
        element_dims = [d for d in st.dims if d not in ("factor", "base_samples")]
        stacked = (
            st.stack(element=element_dims)
            if element_dims
            else st.expand_dims(element=[0])
        )
        conf_st = convergence[f"ST_conf_{name}"]
        conf_s1 = convergence[f"S1_conf_{name}"]
        if element_dims:
            conf_st = conf_st.stack(element=element_dims)
            conf_s1 = conf_s1.stack(element=element_dims)
        else:
            conf_st = conf_st.expand_dims(element=[0])
            conf_s1 = conf_s1.expand_dims(element=[0])
        for e in range(stacked.sizes["element"]):
            label = _element_label(stacked, e, element_dims)
            for k, n in enumerate(convergence["base_samples"].values):
                values = stacked.isel(element=e, base_samples=k).values
                if not np.isfinite(values).any():
                    continue
                top = int(np.nanargmax(values))
                rows.append(
                    {
                        "output": name + label,
                        "base_samples": int(n),
                        "runs": int(convergence["runs"].values[k]),
                        "max_S1_conf": float(
                            np.nanmax(conf_s1.isel(element=e, base_samples=k).values)
                        ),
                        "max_ST_conf": float(
                            np.nanmax(conf_st.isel(element=e, base_samples=k).values)
                        ),
                        "top_factor": str(stacked["factor"].values[top]),
                        "top_ST": float(values[top]),
                    }
                )
    return rows


def _element_label(stacked, e, dims) -> str:
    if not dims:
        return ""
    index = stacked["element"].values[e]
    index = index if isinstance(index, tuple) else (index,)
    return "[" + ", ".join(str(i) for i in index) + "]"
