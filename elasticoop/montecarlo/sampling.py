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

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .study import Study


def _keys(key_data):
    key = jax.random.wrap_key_data(jnp.asarray(key_data, jnp.uint32))
    sample_key, design_key = jax.random.split(key)
    return sample_key, design_key


def lhs_strata(study: Study) -> np.ndarray:
    """The Latin hypercube design: $\\pi_d(s)$ as an `int32` array of shape
    `(n_samples, n_dims)` (memory $4 N D$ bytes; empty for random sampling)."""
    n, d = study.n_samples, study.n_dims
    if study.sampling != "lhs" or d == 0:
        return np.zeros((n, 0), np.int32)
    _, design_key = _keys(study.key_data)

    @jax.jit
    def design(design_key):
        keys = jax.vmap(lambda k: jax.random.fold_in(design_key, k))(jnp.arange(d))
        return jax.vmap(lambda k: jax.random.permutation(k, n))(keys).T

    return np.asarray(design(design_key), dtype=np.int32)


def draw(study: Study, parameters, key_data, index, strata_row) -> dict:
    """The raw draws (before the `relative` scaling) of every parameter for sample
    `index`; `parameters` are the study's (passed separately so that their arrays
    can be traced). `strata_row` is the sample's row of `lhs_strata`."""
    sample_key, _ = _keys(key_data)
    key = jax.random.fold_in(sample_key, index)
    values, offset = {}, 0
    tiny = jnp.finfo(jnp.float64).tiny
    for p_index, p in enumerate(parameters):
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


def sample_parameters(study: Study, indices=None) -> dict[str, np.ndarray]:
    """The parameter values (leaf values, after the `relative` scaling) of the
    samples `indices` (default: all), each of shape `(len(indices), *leaf_shape)`.

    These are exactly the values `run_study` simulates.
    """
    if indices is None:
        indices = np.arange(study.n_samples)
    indices = np.asarray(indices, dtype=np.int64)
    if indices.ndim != 1 or np.any((indices < 0) | (indices >= study.n_samples)):
        raise ValueError(
            f"indices must be a 1-d array of sample numbers in [0, {study.n_samples})"
        )
    strata = lhs_strata(study)[indices]

    @eqx.filter_jit
    def values(parameters, key_data, index, row):
        raw = jax.vmap(lambda s, r: draw(study, parameters, key_data, s, r))(index, row)
        return {p.name: _scaled(p, study, raw[p.name]) for p in parameters}

    return jax.tree.map(
        np.asarray, values(study.parameters, study.key_data, indices, strata)
    )


def _scaled(p, study, raw):
    if p.relative:
        return p.nominal(study.inputs) * raw
    return raw
