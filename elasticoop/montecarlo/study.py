"""`Study`: the specification of a Monte Carlo study (what varies, what is kept)."""

import hashlib
import json
from collections.abc import Callable, Mapping, Sequence

import diffrax
import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._forces import as_force, check_force_shape
from .._models import AbstractElasticModel
from .._simulate import simulate
from .._validation import as_float_array
from .outputs import Output
from .parameters import _RESERVED, Inputs, Parameter

SAMPLING = ("random", "lhs")


def key_data(key) -> np.ndarray:
    """The raw `uint32` data of a `jax.random` key (a seed `int` is turned into
    `jax.random.key(seed)` first)."""
    if isinstance(key, int | np.integer) and not isinstance(key, bool):
        key = jax.random.key(int(key))
    key = jnp.asarray(key)
    if jnp.issubdtype(key.dtype, jax.dtypes.prng_key):
        key = jax.random.key_data(key)
    data = np.asarray(key)
    if data.dtype != np.uint32 or data.shape != (2,):
        raise ValueError(
            f"key must be an int seed or a single jax.random key, got {key!r}"
        )
    return data


class Study:
    """A Monte Carlo study of the elastic system.

    Sample $s$ draws every parameter from its distribution with randomness that
    depends only on `(key, s)` (`jax.random.fold_in`), so results do not depend on
    how the samples are split into chunks or over devices and processes.

    **Arguments:**

    - `model`, `y_init`, `ydot_init`, `ts`, `forces`: the nominal inputs of
      `simulate` (`ts` are the output times of every sample: keep it coarse when
      whole trajectories are kept).
    - `parameters`: a sequence of `Parameter` (the uncertain leaves).
    - `outputs`: a mapping name -> `Output` (or a callable of the `Trajectory`).
    - `n_samples`: number of samples.
    - `key`: a `jax.random` key or an integer seed.
    - `sampling`: `"random"` (independent draws) or `"lhs"` (Latin hypercube: each
      scalar parameter's range is cut into `n_samples` strata of equal probability,
      each hit once).
    - `solver`, `rtol`, `atol`, `max_steps`: passed to `simulate`.
    """

    def __init__(
        self,
        model: AbstractElasticModel,
        y_init,
        ydot_init,
        ts,
        parameters: Sequence[Parameter],
        outputs: Mapping[str, Output | Callable],
        n_samples: int,
        key=0,
        forces=None,
        sampling: str = "random",
        solver: diffrax.AbstractSolver | None = None,
        rtol: float = 1e-8,
        atol: float = 1e-10,
        max_steps: int = 100_000,
    ):
        if not isinstance(model, AbstractElasticModel):
            raise ValueError(
                f"Study.model must be an ImmobileModel or MobileModel, got "
                f"{type(model).__name__}"
            )
        n = model.n_bodies
        y_init = jnp.asarray(as_float_array(y_init, "Study.y_init", (n, 6)))
        ydot_init = jnp.asarray(as_float_array(ydot_init, "Study.ydot_init", (n, 6)))
        ts = as_float_array(ts, "Study.ts", (None,))
        if ts.shape[0] < 2 or not np.all(np.diff(ts) > 0):
            raise ValueError(
                f"Study.ts must hold at least 2 strictly increasing times, got "
                f"{ts.shape[0]} times"
            )
        force = as_force(forces)
        if force is not None:
            check_force_shape(jax.eval_shape(force, ts[0], y_init, ydot_init).shape, n)
        self.inputs = Inputs(model, y_init, ydot_init, force)
        self.ts = ts

        if isinstance(n_samples, bool) or not isinstance(n_samples, int | np.integer):
            raise ValueError(f"Study.n_samples must be an integer, got {n_samples!r}")
        if n_samples < 1:
            raise ValueError(f"Study.n_samples must be >= 1, got {n_samples}")
        self.n_samples = int(n_samples)
        self.key_data = key_data(key)
        if sampling not in SAMPLING:
            raise ValueError(
                f"Study.sampling must be one of {SAMPLING}, got {sampling!r}"
            )
        self.sampling = sampling
        for name, value in (("rtol", rtol), ("atol", atol)):
            if not (np.isfinite(value) and value > 0):
                raise ValueError(
                    f"Study.{name} must be a positive number, got {value!r}"
                )
        if int(max_steps) < 1:
            raise ValueError(f"Study.max_steps must be >= 1, got {max_steps!r}")
        self.solver = diffrax.Tsit5() if solver is None else solver
        self.rtol, self.atol, self.max_steps = float(rtol), float(atol), int(max_steps)

        self.parameters = tuple(parameters)
        self.leaf_shapes = self._check_parameters()
        self.outputs = self._check_outputs(outputs)

    def _check_parameters(self) -> dict:
        shapes = {}
        for k, p in enumerate(self.parameters):
            if not isinstance(p, Parameter):
                raise ValueError(
                    f"Study.parameters[{k}] must be a Parameter, got {p!r}"
                )
            if p.name in shapes:
                raise ValueError(f"Study.parameters: name {p.name!r} is used twice")
            try:
                leaf = p.nominal(self.inputs)
            except (AttributeError, TypeError, IndexError) as err:
                raise ValueError(
                    f"Parameter {p.name!r}: where does not select a leaf of the "
                    f"{p.target}: {err}"
                ) from None
            try:
                eqx.tree_at(p._select, self.inputs, leaf)
            except (TypeError, ValueError):
                raise ValueError(
                    f"Parameter {p.name!r}: where must select a whole leaf "
                    f"(equinox.tree_at-style, e.g. lambda m: m.bodies.mass), not an "
                    f"expression of it such as an indexed entry"
                ) from None
            if not (
                hasattr(leaf, "dtype") and jnp.issubdtype(leaf.dtype, jnp.floating)
            ):
                raise ValueError(
                    f"Parameter {p.name!r}: where must select a float array, got "
                    f"{leaf!r}"
                )
            shape = tuple(leaf.shape)
            try:
                drawn = jax.eval_shape(
                    lambda key, d=p.distribution, s=shape: d.sample(key, s),
                    jax.random.key(0),
                )
            except (ValueError, TypeError) as err:
                raise ValueError(
                    f"Parameter {p.name!r}: the distribution does not fit the leaf's "
                    f"shape {shape}: {err}"
                ) from None
            if drawn.shape != shape:
                raise ValueError(
                    f"Parameter {p.name!r}: the distribution's parameters have shape "
                    f"{drawn.shape}, which does not broadcast to the leaf's shape "
                    f"{shape}"
                )
            if self.sampling == "lhs" and not p.distribution.supports_ppf:
                raise ValueError(
                    f"Parameter {p.name!r}: {type(p.distribution).__name__} has no "
                    f"inverse CDF, so sampling='lhs' is not possible; give it a ppf "
                    f"or use sampling='random'"
                )
            p.leaf_dims(len(shape))
            shapes[p.name] = shape
        return shapes

    def _check_outputs(self, outputs) -> dict:
        if not isinstance(outputs, Mapping) or not outputs:
            raise ValueError(
                f"Study.outputs must be a non-empty mapping name -> Output, got "
                f"{outputs!r}"
            )
        checked = {}
        for name, out in outputs.items():
            if not isinstance(name, str) or not name.isidentifier():
                raise ValueError(
                    f"Study.outputs: name must be an identifier, got {name!r}"
                )
            if name in _RESERVED or name in self.leaf_shapes:
                raise ValueError(
                    f"Study.outputs: name {name!r} clashes with a reserved or "
                    f"parameter name"
                )
            if not isinstance(out, Output):
                if not callable(out):
                    raise ValueError(
                        f"Study.outputs[{name!r}] must be an Output or a callable of "
                        f"the Trajectory, got {out!r}"
                    )
                out = Output(out)
            checked[name] = out
        return checked

    @property
    def n_dims(self) -> int:
        """Number of scalar uncertain parameters (the dimension of the design)."""
        return int(sum(np.prod(s, dtype=int) for s in self.leaf_shapes.values()))

    def simulate(self, inputs: Inputs, **overrides):
        """`simulate` of one sample's `inputs` with the study's times, solver and
        tolerances (never raising: failures are reported in `Trajectory.status`)."""
        kwargs = dict(
            forces=inputs.forces,
            solver=self.solver,
            rtol=self.rtol,
            atol=self.atol,
            max_steps=self.max_steps,
            throw=False,
        )
        kwargs.update(overrides)
        return simulate(
            inputs.model, inputs.y_init, inputs.ydot_init, self.ts, **kwargs
        )

    def describe(self) -> dict:
        """A JSON-able description of the study (recorded in the store's manifest)."""
        return {
            "n_samples": self.n_samples,
            "key": self.key_data.tolist(),
            "sampling": self.sampling,
            "ts": self.ts.tolist(),
            "solver": type(self.solver).__name__,
            "rtol": self.rtol,
            "atol": self.atol,
            "max_steps": self.max_steps,
            "model": type(self.inputs.model).__name__,
            "parameters": [
                {
                    "name": p.name,
                    "target": p.target,
                    "relative": p.relative,
                    "shape": list(self.leaf_shapes[p.name]),
                    "distribution": p.distribution.describe(),
                }
                for p in self.parameters
            ],
            "outputs": {
                name: list(out.dims or ()) for name, out in self.outputs.items()
            },
            "inputs_sha256": _inputs_hash(self.inputs),
        }

    def fingerprint(self) -> str:
        """SHA-256 of `describe()`: equal fingerprints mean the same study."""
        text = json.dumps(self.describe(), sort_keys=True)
        return hashlib.sha256(text.encode()).hexdigest()


def _inputs_hash(inputs: Inputs) -> str:
    digest = hashlib.sha256()
    for leaf in jax.tree.leaves(inputs):
        arr = np.ascontiguousarray(np.asarray(leaf))
        digest.update(str((arr.dtype, arr.shape)).encode())
        digest.update(arr.tobytes())
    return digest.hexdigest()
