"""The summary of a Monte Carlo study's results: sample counts, statistics of the
outputs without a time axis, exceedance probabilities of their thresholds (with
Wilson intervals) and a rank-correlation sensitivity ranking; as a JSON-able
dictionary and as text."""

import math
from collections.abc import Mapping, Sequence
from statistics import NormalDist

import numpy as np
import xarray as xr

from ..montecarlo import (
    exceedance_probability,
    rank_correlations,
    statistics,
    summary as sample_counts,
    valid_samples,
)
from ..montecarlo.correlation import parameter_names

QUANTILES = (0.05, 0.5, 0.95)
CONFIDENCE = 0.95
# Parameters listed per output element in the text (all are in the JSON).
SHOWN_SENSITIVITIES = 4


def output_names(ds: xr.Dataset) -> list[str]:
    """The outputs of a study's results: its variables other than the parameters,
    `status` and `event_time`."""
    skip = {"status", "event_time", *parameter_names(ds)}
    return [str(n) for n in ds.data_vars if n not in skip]


def elements(
    x: xr.DataArray, skip: tuple[str, ...] = ()
) -> list[tuple[dict[str, int], str]]:
    """Every element of a per-sample variable over its axes after the first that
    are not in `skip`: `(isel indices, label)`, the label made of the axes'
    coordinate labels (e.g. `beam-left`), '' for a scalar."""
    dims = [str(d) for d in x.dims[1:] if d not in skip]
    out = []
    for index in np.ndindex(*[x.sizes[d] for d in dims]):
        labels = []
        for dim, k in zip(dims, index):
            coord = x.coords.get(dim)
            labels.append(str(coord.values[k]) if coord is not None else str(k))
        out.append((dict(zip(dims, index)), ", ".join(labels)))
    return out


def element_name(output: str, label: str) -> str:
    return f"{output}[{label}]" if label else output


def study_report(
    ds: xr.Dataset,
    thresholds: Mapping[str, Sequence[float]] | None = None,
    units: Mapping[str, str] | None = None,
) -> dict:
    """The summary of a study's results `ds` (see the module): for each output
    without a time axis, per element, the mean, standard deviation and
    `QUANTILES`, `P(value > threshold)` for each of its `thresholds` with the
    `CONFIDENCE` Wilson interval (failed samples excluded), and Spearman's
    correlation with every varied parameter entry."""
    thresholds = thresholds or {}
    units = units or {}
    report: dict = {
        "samples": sample_counts(ds),
        "complete": bool(ds.attrs.get("complete", 1)),
        "outputs": {},
    }
    for name in output_names(ds):
        x = ds[name]
        entry: dict = {"dims": [str(d) for d in x.dims[1:]], "unit": units.get(name)}
        report["outputs"][name] = entry
        n_valid = int(valid_samples(ds, name).values.sum())
        if "time" in x.dims:
            entry["n_valid"] = n_valid  # a time series: its bands are plotted
            continue
        if not n_valid:
            entry["elements"] = {}
            continue
        stats = statistics(ds, name, QUANTILES)
        probabilities = [
            exceedance_probability(ds, name, t, CONFIDENCE)
            for t in thresholds.get(name, [])
        ]
        entry["elements"] = {}
        for index, label in elements(x):
            element: dict = {
                "mean": float(stats["mean"].isel(index)),
                "std": float(stats["std"].isel(index)),
                "quantiles": {
                    f"{q:g}": float(stats["quantiles"].isel(index | {"quantile": k}))
                    for k, q in enumerate(QUANTILES)
                },
                "n": int(stats["n"]),
                "exceedance": [
                    {
                        "threshold": float(t),
                        "probability": float(p["probability"].isel(index)),
                        "lower": float(p["lower"].isel(index)),
                        "upper": float(p["upper"].isel(index)),
                        "n": int(p["n"]),
                    }
                    for t, p in zip(thresholds.get(name, []), probabilities)
                ],
            }
            if int(stats["n"]) >= 3:
                rho = rank_correlations(ds, name, **index)
                element["rank_correlation"] = {
                    str(k): float(v)
                    for k, v in zip(rho["parameter"].values, rho.values)
                }
            entry["elements"][label] = element
    return report


def format_study_report(report: dict, title: str = "") -> str:
    """`study_report` as text."""
    counts = report["samples"]
    lines = []
    head = f"{title}: " if title else ""
    lines.append(
        f"{head}{counts['n_samples']} samples, {counts['n_succeeded']} succeeded, "
        f"{counts['n_failed']} failed"
        + (
            " (" + ", ".join(f"{k}: {v}" for k, v in counts["failures"].items()) + ")"
            if counts["failures"]
            else ""
        )
        + (
            f"; {counts['n_nonfinite']} with a non-finite output"
            if counts["n_nonfinite"]
            else ""
        )
    )
    if not report["complete"]:
        lines.append("  (the store is not complete: run the study again to finish it)")
    for name, entry in report["outputs"].items():
        unit = f" [{entry['unit']}]" if entry.get("unit") else ""
        if "elements" not in entry:
            lines.append(
                f"{name}{unit}: over time ({', '.join(entry['dims'])}): see the plots"
            )
            continue
        if not entry["elements"]:
            lines.append(f"{name}{unit}: no valid sample")
            continue
        q = [
            f"{float(k) * 100:g}%"
            for k in next(iter(entry["elements"].values()))["quantiles"]
        ]
        lines.append(f"{name}{unit}" + "".join(f"{h:>12}" for h in ("mean", "std", *q)))
        for label, e in entry["elements"].items():
            values = [e["mean"], e["std"], *e["quantiles"].values()]
            lines.append(
                f"  {label or '(value)':<22}" + "".join(f"{v:>12.5g}" for v in values)
            )
        for label, e in entry["elements"].items():
            for p in e["exceedance"]:
                lines.append(
                    f"  P({element_name(name, label)} > {p['threshold']:g}) = "
                    f"{p['probability']:.4f}  ({CONFIDENCE:.0%} CI {p['lower']:.4f} "
                    f"to {p['upper']:.4f}, n = {p['n']})"
                )
    ranked = [
        (element_name(name, label), e["rank_correlation"], e["n"])
        for name, entry in report["outputs"].items()
        for label, e in entry.get("elements", {}).items()
        if e.get("rank_correlation")
    ]
    if ranked:
        # (Spearman's rho of independent quantities: variance 1/(n - 1), normal
        # for large n)
        z = NormalDist().inv_cdf(0.5 + CONFIDENCE / 2)
        lines.append(
            "sensitivity (Spearman rank correlation with the parameters; over n "
            f"samples of independent quantities |rho| stays below {z:.2f}/sqrt(n - 1) "
            f"{CONFIDENCE:.0%} of the time):"
        )
        for what, rho, n in ranked:
            shown = list(rho.items())[:SHOWN_SENSITIVITIES]
            lines.append(
                f"  {what} (n = {n}, chance below {z / math.sqrt(n - 1):.2f}): "
                + ", ".join(f"{p} {v:+.2f}" for p, v in shown)
            )
    return "\n".join(lines)
