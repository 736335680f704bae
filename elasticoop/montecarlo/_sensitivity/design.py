"""A study's sensitivity design: the same study, sampled by the design that an
estimator needs."""

import numbers

import jax
import jax.numpy as jnp

from ..sampling import active_entries, rows_per_point
from ..study import Study

METHODS = ("sobol", "morris", "dgsm")


def design_of(method: str, second_order: bool = False) -> str:
    """The sampling that `method` needs: the Saltelli design for `"sobol"`,
    trajectories for `"morris"`, scrambled Sobol' points for `"dgsm"`."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    if method == "sobol":
        return "saltelli-second-order" if second_order else "saltelli"
    return "morris" if method == "morris" else "sobol"


def sensitivity_study(
    study: Study, method: str = "sobol", base_samples: int = 256, second_order=False
) -> Study:
    """`study` with the design of `method` on `base_samples` base points (Saltelli:
    $N(D+2)$ runs, or $N(2D+2)$ with `second_order`; Morris: $N(D+1)$; DGSM: $N$
    Sobol' points), $D$ the scalar parameters that vary. Everything else is
    `study`'s: the key, parameters, outputs, inputs, what each sample starts from
    (`initial`) and the simulation options."""
    sampling = design_of(method, second_order)
    if (
        isinstance(base_samples, bool)
        or not isinstance(base_samples, numbers.Integral)
        or base_samples < 1
    ):
        raise ValueError(
            f"sensitivity_study: base_samples must be a positive integer, got "
            f"{base_samples!r}"
        )
    if sampling != "morris" and base_samples & (base_samples - 1):
        below = 1 << (int(base_samples).bit_length() - 1)
        raise ValueError(
            f"sensitivity_study: base_samples = {base_samples}: the {method!r} design "
            f"takes a power of two of base points, e.g. {below} or {2 * below}"
        )
    d = int(active_entries(study).sum())
    return Study(
        study.inputs.model,
        study.inputs.y_init,
        study.inputs.ydot_init,
        study.ts,
        parameters=study.parameters,
        outputs=study.outputs,
        n_samples=base_samples * rows_per_point(sampling, d),
        key=jax.random.wrap_key_data(jnp.asarray(study.key_data)),
        forces=study.inputs.forces,
        sampling=sampling,
        body_names=study.body_names,
        connection_names=study.connection_names,
        initial=study.initial,
        options=study.options,
    )
