"""Reproducible draws: sample $s$ depends only on the study key and $s$.

The study key is split once into a *sample key* and a *design key*. Parameter $p$ of
sample $s$ is drawn from `fold_in(fold_in(sample_key, s), p)`, so a sample's values do
not depend on the chunk it falls in, the device that computes it or the number of
processes. Latin hypercube sampling needs one global design: for each of the $D$
scalar parameters a permutation $\\pi_d$ of $0..N-1$ is drawn from
`fold_in(design_key, d)`, and sample $s$ takes
$u_{s,d} = (\\pi_d(s) + v_{s,d})/N$ with $v_{s,d}$ uniform from the sample's own key.
Every stratum $[k/N, (k+1)/N)$ of every scalar parameter is then hit exactly once.
"""

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

# The functions take a `Study` (not imported here: `study` builds on this module).


def _keys(key_data):
    key = jax.random.wrap_key_data(jnp.asarray(key_data, jnp.uint32))
    sample_key, design_key = jax.random.split(key)
    return sample_key, design_key


@partial(jax.jit, static_argnums=(1, 2))
def _design(key_data, n: int, d: int):
    _, design_key = _keys(key_data)
    keys = jax.vmap(lambda k: jax.random.fold_in(design_key, k))(jnp.arange(d))
    return jax.vmap(lambda k: jax.random.permutation(k, n))(keys).T


def lhs_strata(study) -> np.ndarray:
    """The Latin hypercube design: $\\pi_d(s)$ as an `int32` array of shape
    `(n_samples, n_dims)` (memory $4 N D$ bytes; empty for random sampling)."""
    n, d = study.n_samples, study.n_dims
    if study.sampling != "lhs" or d == 0:
        return np.zeros((n, 0), np.int32)
    return np.asarray(_design(study.key_data, n, d), dtype=np.int32)


def draw(study, index, strata_row) -> dict:
    """The raw draws (before the `relative` scaling) of every parameter for sample
    `index`. `strata_row` is the sample's row of `lhs_strata`. `study` may be traced
    (its key and distributions' arrays are leaves; shapes and sampling are static)."""
    sample_key, _ = _keys(study.key_data)
    key = jax.random.fold_in(sample_key, index)
    values, offset = {}, 0
    tiny = jnp.finfo(jnp.float64).tiny
    for p_index, p in enumerate(study.parameters):
        shape = study.leaf_shapes[p.name]
        size = int(np.prod(shape, dtype=int))
        p_key = jax.random.fold_in(key, p_index)
        if study.sampling == "lhs":
            v = jax.random.uniform(p_key, shape, minval=tiny, maxval=1.0)
            strata = strata_row[offset : offset + size].reshape(shape)
            u = (strata.astype(jnp.float64) + v) / study.n_samples
            values[p.name] = p.distribution.ppf(u)
        else:
            values[p.name] = p.distribution.sample(p_key, shape)
        offset += size
    return values


def _scaled(p, inputs, raw):
    """A parameter's leaf value from its raw draw (times the nominal value when
    `relative`)."""
    if p.relative:
        return p.nominal(inputs) * raw
    return raw


@eqx.filter_jit
def _parameter_values(study, index, strata):
    def one(index, strata_row):
        raw = draw(study, index, strata_row)
        return {p.name: _scaled(p, study.inputs, raw[p.name]) for p in study.parameters}

    return jax.vmap(one)(index, strata)


def sample_parameters(study, indices=None) -> dict[str, np.ndarray]:
    """The parameter values (leaf values, after the `relative` scaling) of the
    samples `indices` (default: all), each of shape `(len(indices), *leaf_shape)`.

    These are exactly the values `run_study` simulates.
    """
    if indices is None:
        indices = np.arange(study.n_samples)
    indices = as_sample_indices(indices, study.n_samples)
    strata = lhs_strata(study)[indices]
    return jax.tree.map(np.asarray, _parameter_values(study, indices, strata))


def as_sample_indices(indices, n_samples: int) -> np.ndarray:
    """`indices` as a 1-d int64 array of sample numbers in `[0, n_samples)`, or a
    `ValueError` naming them (a boolean mask or fractional numbers were cast to
    other samples)."""
    raw = np.asarray(indices)
    if raw.dtype.kind not in "iu" and not (raw.size == 0 and raw.dtype.kind == "f"):
        raise ValueError(
            f"indices must be integer sample numbers, got an array of dtype {raw.dtype}"
        )
    indices = raw.astype(np.int64)
    if indices.ndim != 1 or np.any((indices < 0) | (indices >= n_samples)):
        raise ValueError(
            f"indices must be a 1-d array of sample numbers in [0, {n_samples})"
        )
    return indices
