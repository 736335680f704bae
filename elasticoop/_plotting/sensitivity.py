"""Plots of a global sensitivity analysis: Sobol' indices with their intervals,
their evolution over time, their convergence with the number of samples, and
Morris screening."""

import numpy as np
import xarray as xr
from matplotlib.ticker import NullFormatter

from .montecarlo import MAX_PANELS, _elements, _left_out, _panels, every_element


def _own(ds: xr.Dataset, key: str) -> xr.DataArray:
    if key not in ds:
        raise ValueError(f"no {key!r} in the dataset (its variables: {list(ds)})")
    return ds[key].transpose("factor", ...)


def plot_sobol_indices(indices: xr.Dataset, name: str, top: int = 12):
    """First-order and total Sobol' indices of output `name` (of `sobol_indices`)
    with their intervals, the `top` factors by total index, one panel per element
    of the output (at the last time for a time series)."""
    st, s1 = _own(indices, f"ST_{name}"), _own(indices, f"S1_{name}")
    if "time" in st.dims:
        st, s1 = st.isel(time=-1), s1.isel(time=-1)
    conf_st = _own(indices, f"ST_conf_{name}")
    conf_s1 = _own(indices, f"S1_conf_{name}")
    if "time" in conf_st.dims:
        conf_st, conf_s1 = conf_st.isel(time=-1), conf_s1.isel(time=-1)
    elements, _ = _elements(st)
    fig, axes = _panels(len(elements), width=4.6, height=0.32 * top + 1.2)
    for ax, (index, label) in zip(axes, elements):
        total = st.isel(index).values
        order = np.argsort(-np.nan_to_num(total, nan=-1.0), kind="stable")[:top]
        rows = np.arange(len(order))[::-1]
        ax.barh(
            rows + 0.2,
            total[order],
            height=0.4,
            xerr=conf_st.isel(index).values[order],
            color="tab:blue",
            label="total $S_{T,i}$",
            capsize=2,
        )
        ax.barh(
            rows - 0.2,
            s1.isel(index).values[order],
            height=0.4,
            xerr=conf_s1.isel(index).values[order],
            color="tab:orange",
            label="first order $S_i$",
            capsize=2,
        )
        names = [str(f) for f in st["factor"].values[order]]
        ax.set_yticks(rows, names, fontsize="small")
        ax.axvline(0, color="black", linewidth=0.8)
        ax.set_xlabel("share of the variance")
        ax.set_title(label or name, fontsize="medium")
        ax.grid(True, axis="x", alpha=0.3)
    axes[0].legend(fontsize="small", loc="lower right")
    level = indices.attrs.get("confidence", 0.95)
    fig.suptitle(f"{name}: Sobol' indices ({100 * level:g} % intervals)")
    return fig


def plot_sobol_heatmap(indices: xr.Dataset, name: str, index: str = "ST"):
    """The `index` (`"ST"` or `"S1"`) of every factor over time for the time
    series `name`, one heat map per element of its other axes; the elements
    without variance at any time (no index) are left out and named in the title."""
    values = _own(indices, f"{index}_{name}")
    if "time" not in values.dims:
        raise ValueError(f"output {name!r} has no time axis")
    values = values.transpose("factor", "time", ...)
    t = np.asarray(values["time"].values)
    every = every_element(values, ("time",))
    elements = [e for e in every if np.any(np.isfinite(values.isel(e[0]).values))]
    still = [label or name for e, label in every if (e, label) not in elements]
    elements = (elements or every)[:MAX_PANELS]  # none varies: blank maps say so
    n_factors = values.sizes["factor"]
    fig, axes = _panels(len(elements), width=4.6, height=0.22 * n_factors + 1.4)
    image = None
    for ax, (element, label) in zip(axes, elements):
        grid = values.isel(element).values
        image = ax.pcolormesh(
            t,
            np.arange(n_factors),
            grid,
            vmin=0,
            vmax=1,
            cmap="viridis",
            shading="nearest",
        )
        ax.set_yticks(
            np.arange(n_factors), [str(f) for f in values["factor"].values], fontsize=6
        )
        ax.invert_yaxis()
        ax.set_xlabel("time [s]")
        ax.set_title(label or name, fontsize="medium")
    if image is not None:
        fig.colorbar(image, ax=list(axes[: len(elements)]), label=index, shrink=0.8)
    left_out = _left_out(still) if len(still) < len(every) else ""
    fig.suptitle(f"{name}: {index} over time (blank: no variance){left_out}")
    return fig


def plot_sobol_convergence(convergence: xr.Dataset, name: str, top: int = 5):
    """The total indices of the `top` factors of output `name` (no time axis)
    against the model runs, with their intervals (of `sobol_convergence`)."""
    st = _own(convergence, f"ST_{name}").transpose("factor", "base_samples", ...)
    conf = _own(convergence, f"ST_conf_{name}").transpose("factor", "base_samples", ...)
    runs = np.asarray(convergence["runs"].values)
    elements, _ = _elements(st.isel(base_samples=-1, drop=True))
    fig, axes = _panels(len(elements), width=4.2, height=3.0)
    for ax, (index, label) in zip(axes, elements):
        values = st.isel(index).values
        widths = conf.isel(index).values
        last = np.nan_to_num(values[:, -1], nan=-1.0)
        for k in np.argsort(-last, kind="stable")[:top]:
            line = ax.plot(runs, values[k], marker="o", markersize=3)[0]
            ax.fill_between(
                runs,
                values[k] - widths[k],
                values[k] + widths[k],
                color=line.get_color(),
                alpha=0.2,
                label=None,
            )
            line.set_label(str(st["factor"].values[k]))
        ax.set_xscale("log")
        ax.xaxis.set_minor_formatter(NullFormatter())
        ax.set_xticks(runs, [str(r) for r in runs], rotation=45, fontsize="small")
        ax.set_xlabel("model runs")
        ax.set_ylabel("total index $S_{T,i}$")
        ax.set_title(label or name, fontsize="medium")
        ax.grid(True, alpha=0.3)
        ax.legend(fontsize="x-small")
    fig.suptitle(f"{name}: convergence of the total indices")
    return fig


def plot_morris(effects: xr.Dataset, name: str):
    """$\\sigma$ against $\\mu^*$ of the elementary effects on output `name` (of
    `morris_effects`), one panel per element (the last time of a time series)."""
    mu_star, sigma = _own(effects, f"mu_star_{name}"), _own(effects, f"sigma_{name}")
    conf = _own(effects, f"mu_star_conf_{name}")
    if "time" in mu_star.dims:
        mu_star, sigma, conf = (x.isel(time=-1) for x in (mu_star, sigma, conf))
    elements, _ = _elements(mu_star)
    fig, axes = _panels(len(elements), width=4.2, height=3.4)
    for ax, (index, label) in zip(axes, elements):
        x, y = mu_star.isel(index).values, sigma.isel(index).values
        ax.errorbar(x, y, xerr=conf.isel(index).values, fmt="o", markersize=3)
        for k in np.argsort(-np.nan_to_num(x, nan=-1.0))[:6]:
            ax.annotate(str(mu_star["factor"].values[k]), (x[k], y[k]), fontsize=6)
        ax.set_xlabel("$\\mu^*$")
        ax.set_ylabel("$\\sigma$")
        ax.set_title(label or name, fontsize="medium")
        ax.grid(True, alpha=0.3)
    fig.suptitle(f"{name}: Morris elementary effects")
    return fig
