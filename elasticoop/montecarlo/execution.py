"""Chunked, batched, sharded execution of a study.

The samples are cut into chunks of `chunk_size` (chosen from a memory budget), the
unit of storage and of resumption. A chunk runs as batches of
`batch_width x devices` samples: each batch is one array of sample numbers, sharded
over every device of every process (a one-axis `Mesh`, partitioned by `jit`), and
each device integrates its `batch_width` samples at once (`jax.vmap`). One compiled
function serves every chunk size, and every study of the same structure (the
study's arrays are traced, see `Study`). A sample's result depends only on the
study, its number and `batch_width`: not on the chunk size, its position in the
chunk, its neighbours, the number of devices or of processes (bit for bit).
"""

import math
from collections.abc import Callable
from functools import partial
from pathlib import Path

import equinox as eqx
import jax
import numpy as np
import xarray as xr
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from tqdm import tqdm

from .._status import Status
from .distributed import barrier, broadcast_from_first, gather, is_first_process
from .sampling import lhs_strata
from .store import (
    FORMAT,
    completed_chunks,
    concatenate,
    open_study,
    prepare,
    read_manifest,
    to_dataset,
    write_chunk,
)
from .study import INVALID_SAMPLE, Study, one_sample

DEFAULT_BATCH_WIDTH = 32
DEFAULT_MEMORY_BUDGET = 2**30  # bytes
# Working memory of one sample being integrated, in units of its Trajectory's size
# (diffrax's output buffer, the stages and the vmap'd loop's copies), plus a fixed
# part for the solver state. Checked against XLA's memory analysis in
# benchmarks/montecarlo.py.
_WORK_FACTOR = 6
_WORK_FIXED = 64 * 1024
# At most this many batches of lanes in a chunk, so the progress bar moves and a
# killed run loses little.
_MAX_BATCHES_PER_CHUNK = 64


@eqx.filter_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (get_num_traces)
def _run_batch(study: Study, mesh: Mesh, index, strata):
    # The study's arrays are traced and its structure static, so one compilation
    # serves every study of the same structure. `index` has shape
    # (devices, batch_width), axis 0 sharded over the mesh (GSPMD): each device
    # integrates its `batch_width` samples at once (vmap).
    sharded = NamedSharding(mesh, P("samples"))
    index = jax.lax.with_sharding_constraint(index, sharded)
    strata = jax.lax.with_sharding_constraint(strata, sharded)
    return jax.vmap(jax.vmap(partial(one_sample, study)))(index, strata)


def _template(study: Study) -> dict:
    """Shapes and dtypes of one sample's record (computed when the study is made)."""
    return study._record_template()


def _variables(study: Study) -> dict:
    template = _template(study)
    dims: dict[str, tuple[str, ...]] = {"status": (), "event_time": ()}
    for p in study.parameters:
        dims[p.name] = p.leaf_dims(len(study.leaf_shapes[p.name]))
    for name, out in study.outputs.items():
        shape = template[name].shape
        dims[name] = out.dims or tuple(f"{name}_{k}" for k in range(len(shape)))
    return {
        name: {"dims": list(d), "shape": list(template[name].shape)}
        for name, d in dims.items()
    }


def _labels(study: Study) -> dict:
    """Labels of the named axes other than `time` (which the study's `ts` label)."""
    return {k: v for k, v in study._labels().items() if k != "time"}


def working_memory_per_sample(study: Study) -> int:
    """Estimated bytes one sample needs while it is integrated: `_WORK_FACTOR`
    times its trajectory ($Y$ and $\\dot Y$ at the output times) plus
    `_WORK_FIXED`."""
    trajectory = 2 * len(study.ts) * study.inputs.model.n_bodies * 6 * 8
    return _WORK_FACTOR * trajectory + _WORK_FIXED


def chunk_size_for(
    study: Study, memory_budget: int, batch_width: int, n_devices: int = 1
) -> int:
    """The largest chunk (a multiple of `batch_width * n_devices` samples) whose
    memory fits in `memory_budget` bytes.

    Per chunk: `batch_width * n_devices` samples in flight, each needing about
    `_WORK_FACTOR` times its trajectory plus `_WORK_FIXED` bytes, and every sample's
    record held three times (device result, host copy, file buffer).
    """
    record = sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(_template(study)))
    lanes = batch_width * n_devices
    in_flight = lanes * working_memory_per_sample(study)
    if in_flight + 3 * lanes * record > memory_budget:
        raise ValueError(
            f"memory_budget = {memory_budget} bytes is too small for batch_width = "
            f"{batch_width} on {n_devices} device(s): one batch needs about "
            f"{in_flight + 3 * lanes * record} bytes; lower batch_width or the "
            f"number of output times"
        )
    batches = (memory_budget - in_flight) // (3 * lanes * record)
    batches = min(batches, _MAX_BATCHES_PER_CHUNK, math.ceil(study.n_samples / lanes))
    return int(batches * lanes)


def _manifest(study: Study, chunk_size: int, batch_width: int) -> dict:
    return {
        "format": FORMAT,
        "study": study.describe(),
        "fingerprint": study.fingerprint(),
        "chunk_size": chunk_size,
        "batch_width": batch_width,
        "n_chunks": math.ceil(study.n_samples / chunk_size),
        "variables": _variables(study),
        "coords": _labels(study),
        "status_codes": {s.name: int(s) for s in Status}
        | {"INVALID_SAMPLE": INVALID_SAMPLE},
    }


def _global_array(mesh: Mesh, host: np.ndarray, spec=P("samples")) -> jax.Array:
    sharding = NamedSharding(mesh, spec)
    return jax.make_array_from_callback(host.shape, sharding, lambda i: host[i])


def _replicated(mesh: Mesh, study: Study) -> Study:
    """`study` with every array replicated over the mesh (one global array each, so
    that a study spread over processes passes them like the sample numbers)."""

    def put(x):
        return _global_array(mesh, np.asarray(x), P()) if eqx.is_array(x) else x

    return jax.tree.map(put, study)


def run_study(
    study: Study,
    store: str | Path | None = None,
    *,
    chunk_size: int | None = None,
    batch_width: int = DEFAULT_BATCH_WIDTH,
    memory_budget: int = DEFAULT_MEMORY_BUDGET,
    devices=None,
    progress: bool = True,
    on_chunk: Callable[[int], None] | None = None,
) -> xr.Dataset:
    """Simulate every sample of `study`, chunk by chunk.

    **Arguments:**

    - `study`: a `Study`.
    - `store`: a directory for the results (created; resumed when it already holds
      this study: complete chunks are skipped). `None` keeps results in memory.
    - `chunk_size`: samples per chunk (default: from `memory_budget`; a resumed
      store keeps its own).
    - `batch_width`: samples integrated together by `vmap` on each device. Results
      depend on it at the level of floating-point rounding, so it is recorded.
    - `memory_budget`: bytes the chunk may use (sets the default `chunk_size`).
    - `devices`: devices to shard over (default: `jax.devices()`, i.e. every
      device of every process after `jax.distributed.initialize`).
    - `progress`: show a progress bar (samples done, rate, ETA) on the first process.
    - `on_chunk`: called with the chunk number after each chunk is stored.

    **Returns:** an `xarray.Dataset` with dimension `sample`: the drawn parameter
    values, the outputs, `status` (`Status` codes; -1 for a sample whose drawn
    parameters are not finite) and `event_time`. A failed sample never stops the
    study; its outputs are NaN.
    """
    if not isinstance(study, Study):
        raise ValueError(f"study must be a Study, got {type(study).__name__}")
    if (
        isinstance(batch_width, bool)
        or not isinstance(batch_width, int)
        or batch_width < 1
    ):
        raise ValueError(f"batch_width must be a positive integer, got {batch_width!r}")
    devices = list(jax.devices() if devices is None else devices)
    mesh = Mesh(np.array(devices), ("samples",))
    lanes = batch_width * len(devices)

    existing = None if store is None else read_manifest(store)
    if existing is not None:
        if chunk_size is not None and chunk_size != existing["chunk_size"]:
            raise ValueError(
                f"chunk_size = {chunk_size}, but the store {store} was started with "
                f"chunk_size = {existing['chunk_size']}; omit chunk_size to resume"
            )
        chunk_size = existing["chunk_size"]
    elif chunk_size is None:
        chunk_size = chunk_size_for(study, memory_budget, batch_width, len(devices))
    if (
        isinstance(chunk_size, bool)
        or not isinstance(chunk_size, int)
        or chunk_size < 1
    ):
        raise ValueError(f"chunk_size must be a positive integer, got {chunk_size!r}")
    manifest = _manifest(study, chunk_size, batch_width)
    n_chunks = manifest["n_chunks"]

    done = np.zeros(n_chunks, dtype=bool)
    if store is not None:
        if is_first_process():
            prepare(store, manifest)
            done[[c for c in completed_chunks(store) if c < n_chunks]] = True
        done = broadcast_from_first(done)
        barrier("elasticoop-montecarlo-prepared")

    strata = lhs_strata(study)
    traced = _replicated(mesh, study)
    in_memory = []
    n_done = int(
        sum(
            min(chunk_size, study.n_samples - int(c) * chunk_size)
            for c in np.flatnonzero(done)
        )
    )
    bar = tqdm(
        total=study.n_samples,
        initial=n_done,
        unit="sample",
        desc="Monte Carlo",
        disable=not (progress and is_first_process()),
    )
    failed = 0
    with bar:
        for chunk in range(n_chunks):
            if done[chunk]:
                continue
            start = chunk * chunk_size
            stop = min(start + chunk_size, study.n_samples)
            padded = math.ceil((stop - start) / lanes) * lanes
            index = np.minimum(np.arange(start, start + padded), stop - 1)
            launches = [
                _run_batch(
                    traced,
                    mesh,
                    _global_array(mesh, part.reshape(len(devices), batch_width)),
                    _global_array(
                        mesh, strata[part].reshape(len(devices), batch_width, -1)
                    ),
                )
                for part in index.reshape(-1, lanes)
            ]
            record = gather(launches)
            record = {
                k: np.concatenate([r[k].reshape(-1, *r[k].shape[2:]) for r in record])[
                    : stop - start
                ]
                for k in record[0]
            }
            if store is None:
                in_memory.append(record)
            elif is_first_process():
                write_chunk(store, chunk, record)
            failed += int(np.sum(record["status"] != Status.SUCCESS))
            bar.update(stop - start)
            bar.set_postfix(failed=failed)
            if on_chunk is not None:
                on_chunk(chunk)
    if store is None:
        return to_dataset(concatenate(in_memory), manifest)
    barrier("elasticoop-montecarlo-finished")
    return open_study(store)
