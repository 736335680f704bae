"""Reproducible draws: sample $s$ depends only on the study key and $s$.

The study key is split once into a *sample key* and a *design key*. Parameter $p$ of
sample $s$ is drawn from `fold_in(fold_in(sample_key, s), p)`, so a sample's values do
not depend on the chunk it falls in, the device that computes it or the number of
processes. Latin hypercube sampling needs one global design: for each of the $D$
scalar parameters a permutation $\\pi_d$ of $0..N-1$ is drawn from
`fold_in(design_key, d)`, and sample $s$ takes
$u_{s,d} = (\\pi_d(s) + v_{s,d})/N$ with $v_{s,d}$ uniform from the sample's own key.
Every stratum $[k/N, (k+1)/N)$ of every scalar parameter is then hit exactly once.

The quasi-Monte Carlo designs (`QMC_DESIGNS`) are one global table $u_{s,d}$ of
points of the unit cube over the $D_a$ scalar parameters that vary (those whose
law is not a single value; the others take their median), made once on the host
with a generator seeded by the study key, and sample $s$ takes $x = F^{-1}(u_s)$:

- `"sobol"`: scrambled Sobol' points (`scipy.stats.qmc.Sobol`, LMS and digital
  shift), $N$ a power of two (their balance properties hold for such $N$);
- `"saltelli"` / `"saltelli-second-order"`: Saltelli's cross-sampling design for
  Sobol' indices (`SALib.sample.sobol.sample`) on $N$ scrambled Sobol' base points
  of dimension $2D_a$: rows $A$, $AB_1..AB_{D_a}$ (, $BA_1..BA_{D_a}$), $B$ per base
  point, $N(D_a+2)$ rows (or $N(2D_a+2)$), $N$ a power of two;
- `"morris"`: $N$ Morris trajectories of $D_a+1$ points on a grid of
  `MORRIS_LEVELS` levels (`SALib.sample.morris.sample`), level $l$ placed at the
  centre $u = (l + 1/2)/L$ of its stratum of equal probability (so that unbounded
  laws stay finite).

In each of them row $s$ depends only on the key and $s$, never on the number of
samples (the Sobol' sequence and the trajectories are drawn in order), so a study
can be extended with more samples and keep the rows it has.
"""

from functools import partial

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

QMC_DESIGNS = ("sobol", "saltelli", "saltelli-second-order", "morris")
MORRIS_LEVELS = 4
# Keeps u off 0 and 1, where the inverse CDF of an unbounded law is infinite.
_U_EDGE = 2.0**-53

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
    """The design's rows: for Latin hypercube sampling $\\pi_d(s)$ as an `int32`
    array of shape `(n_samples, n_dims)` (memory $4 N D$ bytes), for a design of
    `QMC_DESIGNS` its points $u_s$ of the unit cube as `float64` (`unit_design`);
    empty for random sampling."""
    n, d = study.n_samples, study.n_dims
    if study.sampling in QMC_DESIGNS:
        return unit_design(study)
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
        if study.sampling in QMC_DESIGNS:
            u = strata_row[offset : offset + size].reshape(shape)
            values[p.name] = p.distribution.ppf(u)
        elif study.sampling == "lhs":
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


def design_row_template(study) -> jax.ShapeDtypeStruct:
    """Shape and dtype of one row of `lhs_strata`."""
    if study.sampling in QMC_DESIGNS:
        return jax.ShapeDtypeStruct((study.n_dims,), jnp.float64)
    d = study.n_dims if study.sampling == "lhs" else 0
    return jax.ShapeDtypeStruct((d,), jnp.int32)


def active_entries(study) -> np.ndarray:
    """Which of the `n_dims` scalar parameters vary (a boolean array, parameters in
    order, each leaf flattened in C order): those whose leaf value is not a single
    value ($F^{-1}(1/4) \\ne F^{-1}(3/4)$, after the `relative` scaling)."""
    parts = []
    for p in study.parameters:
        shape = study.leaf_shapes[p.name]
        if not p.distribution.supports_ppf:
            parts.append(np.ones(int(np.prod(shape, dtype=int)), bool))
            continue
        low = _scaled(p, study.inputs, p.distribution.ppf(jnp.full(shape, 0.25)))
        high = _scaled(p, study.inputs, p.distribution.ppf(jnp.full(shape, 0.75)))
        parts.append(np.ravel(np.asarray(low) != np.asarray(high)))
    return np.concatenate(parts) if parts else np.zeros(0, bool)


def rows_per_point(sampling: str, n_active: int) -> int:
    """Rows of the design per base point (`"sobol"`: 1; Saltelli: $D_a+2$ or
    $2D_a+2$; Morris: $D_a+1$ per trajectory); 1 for the other samplings."""
    return {
        "saltelli": n_active + 2,
        "saltelli-second-order": 2 * n_active + 2,
        "morris": n_active + 1,
    }.get(sampling, 1)


def check_design(study) -> None:
    """Refuse a number of samples that the study's design cannot have, naming the
    ones it can (a `ValueError`)."""
    if study.sampling not in QMC_DESIGNS:
        return
    d = int(active_entries(study).sum())
    what = f"Study.n_samples = {study.n_samples} with sampling={study.sampling!r}"
    if d == 0:
        raise ValueError(f"{what}: no parameter varies (every law is one value)")
    block = rows_per_point(study.sampling, d)
    n = study.n_samples // block
    power = n >= 1 and n & (n - 1) == 0
    if study.sampling == "morris":
        power = n >= 1
    if study.n_samples % block or not power:
        shape = "N" if block == 1 else f"N x {block}"
        rule = "" if study.sampling == "morris" else ", N a power of two"
        near = 2 ** max(int(np.log2(max(n, 1))), 0)
        example = study.n_samples if study.sampling == "morris" else near * block
        raise ValueError(
            f"{what}: the design has {shape} rows ({d} varying scalar parameters)"
            f"{rule}; for example n_samples = {example}"
        )


def unit_design(study) -> np.ndarray:
    """The points $u_s$ of the unit cube of a design of `QMC_DESIGNS`, shape
    `(n_samples, n_dims)` (`float64`; $1/2$ for the parameters that do not vary).
    """
    active = active_entries(study)
    d = int(active.sum())
    n = study.n_samples
    block = rows_per_point(study.sampling, d)
    u = design_points(study.sampling, study.key_data, d, n // block)
    full = np.full((n, study.n_dims), 0.5)
    full[:, active] = u
    return full


def design_points(sampling: str, key_data, d: int, n_points: int) -> np.ndarray:
    """The rows of the design `sampling` (of `QMC_DESIGNS`) on $(0, 1)^d$ with
    `n_points` base points, as the study of key `key_data` draws them."""
    from scipy.stats import qmc

    rng = np.random.default_rng(np.asarray(key_data).tolist())
    if sampling == "sobol":
        u = qmc.Sobol(d, scramble=True, seed=rng).random(n_points)
    elif sampling == "morris":
        grid = morris_grid(key_data, d, n_points)
        u = (grid * (MORRIS_LEVELS - 1) + 0.5) / MORRIS_LEVELS
    else:
        from SALib.sample import sobol as saltelli

        problem = {"num_vars": d, "bounds": [[0.0, 1.0]] * d}
        second = sampling == "saltelli-second-order"
        u = saltelli.sample(problem, n_points, calc_second_order=second, seed=rng)
    return np.clip(u, _U_EDGE, 1.0 - _U_EDGE)


def morris_grid(key_data, d: int, n_trajectories: int) -> np.ndarray:
    """The Morris design of `SALib.sample.morris.sample` on $[0, 1]^d$ (grid levels
    $l/(L-1)$), as the study of key `key_data` draws it."""
    from SALib.sample import morris

    rng = np.random.default_rng(np.asarray(key_data).tolist())
    problem = {
        "num_vars": d,
        "names": [f"x{k}" for k in range(d)],
        "bounds": [[0.0, 1.0]] * d,
    }
    return morris.sample(problem, n_trajectories, num_levels=MORRIS_LEVELS, seed=rng)
