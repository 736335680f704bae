"""The factors of a global sensitivity analysis: the scalar parameters a study's
design varies, read from its results (a `run_study` / `open_study` dataset)."""

import dataclasses
import json

import numpy as np
import xarray as xr

from ..._status import Status


@dataclasses.dataclass(frozen=True)
class Factors:
    """The varying scalar parameters of a study's results.

    - `labels`: one per factor, e.g. `"stiffness[plate-left, x]"`.
    - `values`: their values in every sample, shape `(samples, factors)`.
    - `study`: the study's description (`Study.describe()`).
    """

    labels: tuple[str, ...]
    values: np.ndarray
    study: dict

    @property
    def sampling(self) -> str:
        return str(self.study["sampling"])

    @property
    def key(self) -> list[int]:
        return list(self.study["key"])

    def __len__(self) -> int:
        return len(self.labels)


def study_description(results: xr.Dataset) -> dict:
    """The study's description recorded in `results` (a `ValueError` when it holds
    none: it is not the result of `run_study` or `open_study`)."""
    if not isinstance(results, xr.Dataset) or "study" not in results.attrs:
        raise ValueError(
            "results must be the dataset of run_study or open_study (it records "
            "the study in attrs['study'])"
        )
    return json.loads(results.attrs["study"])


def factors_of(results: xr.Dataset) -> Factors:
    """The scalar parameters that vary over the samples of `results`, in the order
    of the design (parameters in order, each leaf in C order)."""
    study = study_description(results)
    labels, columns = [], []
    for p in study["parameters"]:
        values = results[p["name"]]
        flat = values.values.reshape(values.shape[0], -1)
        names = list(np.ndindex(values.shape[1:]))
        for k, index in enumerate(names):
            column = flat[:, k]
            if not np.ptp(column) > 0:
                continue
            labels.append(_label(results, p["name"], values.dims[1:], index))
            columns.append(column)
    values = (
        np.stack(columns, axis=1) if columns else np.zeros((results.sizes["sample"], 0))
    )
    return Factors(tuple(labels), values, study)


def _label(results, name: str, dims, index) -> str:
    parts = []
    for dim, i in zip(dims, index):
        if dim in results.coords:
            parts.append(str(results[dim].values[i]))
        else:
            parts.append(str(i))
    return f"{name}[{', '.join(parts)}]" if parts else name


def output_names(results: xr.Dataset, outputs=None) -> list[str]:
    """The outputs to analyse: `outputs` (checked) or every output of the study."""
    known = list(study_description(results)["outputs"])
    if outputs is None:
        return known
    if isinstance(outputs, str):
        outputs = [outputs]
    unknown = [o for o in outputs if o not in known]
    if unknown:
        raise ValueError(
            f"no output {unknown[0]!r} in the study (its outputs: {', '.join(known)})"
        )
    return list(outputs)


def output_columns(results: xr.Dataset, name: str) -> tuple[np.ndarray, np.ndarray]:
    """The output's values as columns, shape `(samples, elements)`, and which of
    them are usable (the sample succeeded and the value is finite)."""
    y = results[name].values.reshape(results.sizes["sample"], -1).astype(np.float64)
    ok = (results["status"].values == Status.SUCCESS)[:, None] & np.isfinite(y)
    return y, ok


def element_coords(results: xr.Dataset, name: str) -> dict:
    """The coordinates of the output's own dimensions (those `results` labels)."""
    dims = results[name].dims[1:]
    return {d: results[d] for d in dims if d in results.coords}
