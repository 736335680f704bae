"""Plots of a Monte Carlo study's results: quantile bands of the outputs over time,
histograms of the outputs without a time axis (with their thresholds), and the
rank-correlation sensitivity ranking. Every function returns the Figure. An element
of an output that takes one value in every valid sample at every time (a
coordinate that never moves, such as y in a planar lift) gets no panel; the title
names the elements left out."""

import math

import numpy as np
import xarray as xr

from .._io.study_summary import elements as every_element
from ..montecarlo import rank_correlations, statistics, valid_samples
from ._common import new_figure

# At most this many panels per figure (one per element of the output).
MAX_PANELS = 24
# Bands of the quantile plot: (lower, upper) quantiles, from wide to narrow.
BANDS = ((0.05, 0.95), (0.25, 0.75))
# An element whose valid values spread by no more than this, relative to their
# size (or absolutely below 1), never moves.
STILL = 1e-9


def _still(values: np.ndarray) -> bool:
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return False  # no valid value: shown (empty), not taken for constant
    return float(np.ptp(finite)) <= STILL * max(1.0, float(np.max(np.abs(finite))))


def _elements(
    x: xr.DataArray, skip: tuple[str, ...] = (), ok=None
) -> tuple[list[tuple[dict, str]], list[str]]:
    """`(isel indices, label)` of every element over the axes not in `skip` whose
    values over the samples `ok` (default all) and the skipped axes vary, and the
    labels of those that do not (all of them are kept when none varies)."""
    ok = np.ones(x.shape[0], bool) if ok is None else np.asarray(ok)
    moving: list[tuple[dict, str]] = []
    still: list[tuple[dict, str]] = []
    for element in every_element(x, skip):
        values = np.asarray(x.isel(element[0]).values)[ok]
        (still if _still(values) else moving).append(element)
    if not moving:
        return still[:MAX_PANELS], []
    return moving[:MAX_PANELS], [label for _, label in still]


def _left_out(still: list[str]) -> str:
    if not still:
        return ""
    shown = ", ".join(still[:8]) + (", ..." if len(still) > 8 else "")
    return f"\n(constant in every sample, not shown: {shown})"


def _panels(n: int, width: float = 3.2, height: float = 2.4):
    cols = min(n, 3)
    rows = math.ceil(n / cols)
    fig = new_figure(width * cols + 0.6, height * rows + 0.6)
    axes = fig.subplots(rows, cols, squeeze=False).ravel()
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes


def plot_study_quantiles(ds: xr.Dataset, name: str, unit: str | None = None):
    """The median of output `name` over time with its 25-75 % and 5-95 % bands over
    the valid samples, one panel per element of its other axes."""
    x = ds[name]
    if "time" not in x.dims:
        raise ValueError(f"output {name!r} has no time axis")
    qs = sorted({q for band in BANDS for q in band} | {0.5})
    stats = statistics(ds, name, qs)
    t = np.asarray(x.coords["time"].values)
    elements, still = _elements(x, ("time",), valid_samples(ds, name).values)
    fig, axes = _panels(len(elements))
    for ax, (index, label) in zip(axes, elements):
        quant = stats["quantiles"].isel(index)
        for alpha, (lo, hi) in zip((0.2, 0.35), BANDS):
            ax.fill_between(
                t,
                quant.sel(quantile=lo).values,
                quant.sel(quantile=hi).values,
                alpha=alpha,
                color="tab:blue",
                linewidth=0,
                label=f"{lo:.0%}-{hi:.0%}",
            )
        ax.plot(t, quant.sel(quantile=0.5).values, color="tab:blue", label="median")
        ax.set_title(label or name, fontsize="medium")
        ax.set_xlabel("time [s]")
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel(f"{name}" + (f" [{unit}]" if unit else ""))
    axes[0].legend(fontsize="small")
    fig.suptitle(f"{name}: quantiles over {int(stats['n'])} samples" + _left_out(still))
    return fig


def plot_study_histograms(
    ds: xr.Dataset, name: str, thresholds=(), unit: str | None = None, bins=30
):
    """Histograms of output `name` (no time axis) over the valid samples, one
    panel per element, with its `thresholds` as vertical lines."""
    x = ds[name]
    ok = valid_samples(ds, name).values
    elements, still = _elements(x, ok=ok)
    fig, axes = _panels(len(elements))
    for ax, (index, label) in zip(axes, elements):
        values = x.isel(index).values[ok]
        ax.hist(values, bins=bins, color="tab:blue", alpha=0.8)
        for t in thresholds:
            ax.axvline(t, color="tab:red", linestyle="--", label=f"threshold {t:g}")
        ax.set_title(label or name, fontsize="medium")
        ax.set_xlabel(name + (f" [{unit}]" if unit else ""))
        ax.grid(True, alpha=0.3)
    axes[0].set_ylabel("samples")
    if len(thresholds):
        axes[0].legend(fontsize="small")
    fig.suptitle(f"{name}: {int(ok.sum())} samples" + _left_out(still))
    return fig


def plot_study_sensitivity(ds: xr.Dataset, name: str, top: int = 10):
    """Spearman's rank correlation of output `name` (no time axis) with each
    varied parameter entry, the `top` largest in magnitude, one panel per
    element."""
    elements, still = _elements(ds[name], ok=valid_samples(ds, name).values)
    fig, axes = _panels(len(elements), width=4.2, height=0.35 * top + 1.0)
    for ax, (index, label) in zip(axes, elements):
        rho = rank_correlations(ds, name, **index)[:top]
        rows = np.arange(len(rho))[::-1]
        colours = ["tab:red" if v > 0 else "tab:blue" for v in rho.values]
        ax.barh(rows, rho.values, color=colours)
        ax.set_yticks(rows, [str(p) for p in rho["parameter"].values], fontsize="small")
        ax.set_xlim(-1, 1)
        ax.axvline(0, color="black", linewidth=0.8)
        ax.set_xlabel("Spearman rank correlation")
        ax.set_title(label or name, fontsize="medium")
        ax.grid(True, axis="x", alpha=0.3)
    fig.suptitle(f"{name}: sensitivity to the parameters" + _left_out(still))
    return fig
