"""Local sensitivities by forward-mode autodiff, and a first-order variance ranking.

For sample $s$ with parameter values $\\theta_s$ the Jacobian
$J_s = \\partial y/\\partial\\theta\\,|_{\\theta_s}$ of every output $y$ is computed
with `jax.jacfwd` through `simulate` (`diffrax.ForwardMode`: one tangent per scalar
parameter, pushed through the adaptive solver). Linearising $y$ about each sample,
independent parameters contribute

$$V_j = \\mathbb E_s\\big[J_{s,j}^2\\big]\\,\\operatorname{Var}(\\theta_j)$$

to $\\operatorname{Var}(y)$ (first-order variance decomposition); `variance_ranking`
sorts the parameters by $V_j / \\sum_k V_k$.
"""

import numbers

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import xarray as xr

from .._status import Status
from .execution import _variables
from .sampling import as_sample_indices, sample_parameters
from .store import axis_labels
from .study import INVALID_SAMPLE, Study, admissible_inputs


def _outputs_at(study: Study, values: dict) -> tuple[dict, jax.Array]:
    """The outputs at the parameter values, and the status (`INVALID_SAMPLE`
    where the values give inputs no constructor would accept, as in `run_study`;
    the outputs are then those of the values as given)."""
    inputs = study.inputs
    for p in study.parameters:
        inputs = eqx.tree_at(p._select, inputs, values[p.name])
    valid = admissible_inputs(inputs)
    inputs = study.start(inputs)  # the rest state of these values, if so
    traj = study.simulate(inputs, adjoint=diffrax.ForwardMode())
    status = jnp.where(valid, traj.status, INVALID_SAMPLE).astype(jnp.int32)
    return {name: out(traj) for name, out in study.outputs.items()}, status


@eqx.filter_jit
def _jacobians(study: Study, values: dict):
    def one(theta):
        # the outputs and status are those of the run that carries the tangents
        # (one simulation of the sample, not two)
        def outputs_with_aux(t):
            outputs, status = _outputs_at(study, t)
            return outputs, (outputs, status)

        jac, (outputs, status) = jax.jacfwd(outputs_with_aux, has_aux=True)(theta)
        return jac, outputs, status

    return jax.vmap(one)(values)


def jacobian_name(output: str, parameter: str) -> str:
    return f"d_{output}_d_{parameter}"


def local_sensitivities(study: Study, indices=None, batch_width: int = 8) -> xr.Dataset:
    """$\\partial y/\\partial\\theta$ of every output with respect to every
    parameter leaf (the leaf's value itself, also for `relative` parameters), at
    the samples `indices` (default: all).

    **Returns:** an `xarray.Dataset` with the parameter values, the outputs,
    `status`, and for each output/parameter pair a variable
    `d_{output}_d_{parameter}` with dimensions (sample, output dims...,
    parameter dims...). Cost: about (1 + number of scalar parameters) simulations
    per sample.
    """
    if (
        isinstance(batch_width, bool)
        or not isinstance(batch_width, numbers.Integral)
        or batch_width < 1
    ):
        raise ValueError(f"batch_width must be a positive integer, got {batch_width!r}")
    batch_width = int(batch_width)
    if indices is None:
        indices = np.arange(study.n_samples)
    indices = as_sample_indices(indices, study.n_samples)
    if indices.size == 0:
        raise ValueError("indices must name at least one sample, got none")
    values = sample_parameters(study, indices)
    n = indices.shape[0]
    padded = -(-n // batch_width) * batch_width
    pad = np.minimum(np.arange(padded), n - 1)
    parts = []
    program = study._program_view()
    for start in range(0, padded, batch_width):
        rows = pad[start : start + batch_width]
        batch = {k: jnp.asarray(v[rows]) for k, v in values.items()}
        parts.append(_jacobians(program, batch))
    jac, outputs, status = jax.tree.map(
        lambda *xs: np.concatenate([np.asarray(x) for x in xs])[:n], *parts
    )

    dims = {k: spec["dims"] for k, spec in _variables(study).items()}
    data = {"status": (("sample",), status)}
    for name, v in values.items():
        data[name] = (("sample", *dims[name]), v)
    for out_name, out in outputs.items():
        data[out_name] = (("sample", *dims[out_name]), out)
        for p_name in values:
            p_dims = [f"{d}_wrt" if d in dims[out_name] else d for d in dims[p_name]]
            data[jacobian_name(out_name, p_name)] = (
                ("sample", *dims[out_name], *p_dims),
                jac[out_name][p_name],
            )
    coords = axis_labels(dims.values(), study.ts, study._labels())
    return xr.Dataset(data, coords={"sample": indices} | coords)


def variance_ranking(sensitivities: xr.Dataset, output: str, **select) -> xr.DataArray:
    """Rank scalar parameters by their first-order share of $\\operatorname{Var}(y)$.

    **Arguments:**

    - `sensitivities`: the result of `local_sensitivities`.
    - `output`: the output's name; `select` picks one element of it by index
      (`xarray.Dataset.isel` keywords, e.g. `connection=0`) when it is not scalar.

    **Returns:** a `DataArray` over dimension `parameter` (labels like
    `"stiffness[1, 2]"`), sorted by decreasing share $V_j/\\sum_k V_k$, with
    `attrs["linearized_variance"]` $= \\sum_k V_k$ and `attrs["sample_variance"]`,
    the variance of $y$ over the same samples, to judge the linearisation.
    """
    if output not in sensitivities.data_vars:
        raise ValueError(f"no output {output!r} in the sensitivities")
    y = sensitivities[output].isel(select)
    if y.ndim != 1:
        raise ValueError(
            f"output {output!r} is not scalar per sample (dims {y.dims[1:]}); pick "
            f"an element, e.g. variance_ranking(sens, {output!r}, "
            f"{y.dims[1]}=0)"
        )
    prefix = f"d_{output}_d_"
    names = [
        str(k)[len(prefix) :]
        for k in sensitivities.data_vars
        if str(k).startswith(prefix)
    ]
    jacs = {p: sensitivities[prefix + p].isel(select) for p in names}
    ok = (sensitivities["status"] == Status.SUCCESS).values & np.isfinite(y.values)
    for j in jacs.values():
        ok &= np.all(np.isfinite(j.values.reshape(j.shape[0], -1)), axis=1)
    if ok.sum() < 2:
        raise ValueError("fewer than 2 valid samples: cannot estimate variances")
    labels: list[str] = []
    values: list[float] = []
    for p, j in jacs.items():
        theta = sensitivities[p].values[ok]
        var_theta = theta.var(axis=0, ddof=1)
        v = np.mean(j.values[ok] ** 2, axis=0) * var_theta
        for idx in np.ndindex(v.shape):
            labels.append(f"{p}[{', '.join(map(str, idx))}]" if idx else p)
            values.append(v[idx])
    contributions = np.asarray(values)
    total = contributions.sum()
    order = np.argsort(-contributions, kind="stable")
    share = contributions / total if total > 0 else contributions
    return xr.DataArray(
        share[order],
        dims=("parameter",),
        coords={"parameter": np.asarray(labels)[order]},
        name=f"variance_share_{output}",
        attrs={
            "linearized_variance": float(total),
            "sample_variance": float(np.var(y.values[ok], ddof=1)),
        },
    )
