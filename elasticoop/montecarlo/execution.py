"""Chunked, batched, sharded execution of a study.

The samples are cut into chunks of `chunk_size` (chosen from a memory budget), the
unit of storage and of resumption. A chunk is one array of sample numbers, split
over every device of every process (a one-axis `Mesh`, `jax.shard_map`), and each
device integrates its part `batch_width` samples at a time, in one loop of its own
in which each waiting sample starts as soon as one stops (`jax.vmap` of
`simulate(..., batch_loop=batch_width)`). Every chunk has the length of the first
(the last one is padded with samples that stop at their first step), so one
compilation serves a whole study, and every study of the same structure and chunk
size (the study's arrays are traced, see `Study`). A sample's result depends only
on the study, its number and `batch_width`: not on the chunk size, its position in
the chunk, its neighbours, the number of devices or of processes (bit for bit).
"""

import contextlib
import importlib.metadata
import math
import numbers
import platform
import sys
from collections.abc import Callable
from functools import partial
from pathlib import Path

import diffrax
import equinox as eqx
import jax
import numpy as np
import xarray as xr
from jax.sharding import Mesh, NamedSharding, PartitionSpec as P
from tqdm import tqdm

from .._compile_options import fast_compile_jit
from .._sizes import format_bytes
from .._status import Status
from .._version import __version__
from .distributed import barrier, broadcast_from_first, gather, is_first_process
from .lock import store_lock
from .resources import StudyTooLargeError, free_space, host_memory_budget
from .sampling import lhs_strata
from .store import (
    FORMAT,
    StoreError,
    check_store_folder,
    concatenate,
    open_study,
    prepare,
    read_manifest,
    to_dataset,
    write_chunk,
)
from .study import (
    INVALID_SAMPLE,
    Study,
    combined_fingerprint,
    one_sample,
    sample_start,
)

DEFAULT_BATCH_WIDTH = 128
"""Samples integrated together on each device unless `run_study` is given a
`batch_width` (fewer when the samples do not fill every device, and halved until a
batch fits the memory budget: `default_batch_width`). Among the fastest widths on a
CPU: a wider batch leaves the caches, a narrower one shares the loop's fixed costs
among fewer samples (`python benchmarks/montecarlo.py --batch-widths ...` measures
them; docs/performance.md)."""
ACCELERATOR_BATCH_WIDTH = 2**17
"""The same on GPUs (and any device that is not a CPU): there a batch's steps cost
about the same at any width up to the device's size, so the wider the quicker
(`python benchmarks/montecarlo.py --batches 1024 10240 102400 --batch-widths 1024
8192 102400` measures it; docs/performance.md). The cap keeps a batch short, so
that a long study's progress shows and a killed run loses little."""
DEFAULT_MEMORY_BUDGET = 2**30  # bytes, where the devices do not report their memory
# Share of an accelerator's memory (the smallest of the devices) a chunk may use
# per device when the devices report their memory (GPUs); the rest is left to
# XLA's own buffers and to other programs.
DEVICE_MEMORY_SHARE = 0.5
# Working memory of one sample being integrated, in units of its Trajectory's size
# (diffrax's output buffer, the stages and the vmap'd loop's copies), plus a fixed
# part for the solver state. Checked against XLA's memory analysis in
# benchmarks/montecarlo.py.
_WORK_FACTOR = 6
_WORK_FIXED = 64 * 1024
# Memory of each sample of a chunk while the chunk runs, in units of its
# Trajectory's size: its outputs, kept from when it stops until the chunk ends, and
# its Trajectory when its outputs are reduced.
_CHUNK_FACTOR = 2
# At most this many batches of lanes in a chunk, and at least this many chunks in
# a study where it has that many batches: a chunk is the work a killed run loses,
# so it is kept to a small share of the study and to about a minute at most (see
# `chunk_size_for`).
_MAX_BATCHES_PER_CHUNK = 16
MIN_CHUNKS = 8
# Bytes of a chunk file beyond its numbers (the .npy headers and zip entries of
# each variable), and of each chunk's record in the manifest.
_NPZ_BYTES_PER_VARIABLE = 512
_MANIFEST_BYTES_PER_CHUNK = 160


@fast_compile_jit
def _sample_starts(study: Study, index, strata):
    """The rest states of samples `index` (`initial="equilibrium"`), on one device:
    solved before the sharded batch, not in it (optimistix's solver, a
    `while_loop` over a batch split over several devices, waited forever for the
    devices to agree on when to stop)."""
    return jax.vmap(partial(sample_start, study))(index, strata)


@fast_compile_jit
@eqx.debug.assert_max_traces(max_traces=None)  # counts traces (get_num_traces)
def _run_batch(
    study: Study, mesh: Mesh, index, strata, started, starts, batch_width: int
):
    # The study's arrays are traced and its structure static, so one compilation
    # serves every study of the same structure and chunk size. `index` has shape
    # (devices, samples a device), axis 0 split over the mesh: each device
    # integrates its samples `batch_width` at a time, in its own loop, each waiting
    # sample starting as one stops (`shard_map` of a `vmap` of
    # `simulate(..., batch_loop=batch_width)`), not waiting for the other devices.
    # Where `started` is false (the padding of a last chunk) the sample stops at
    # its first step. `starts`: the samples' rest states (`initial="equilibrium"`,
    # `_sample_starts`), split over the devices as the samples are; else empty.
    arrays, static = eqx.partition(study, eqx.is_array)

    def on_device(arrays, index, strata, started, starts):
        study = eqx.combine(arrays, static)

        def sample(index, strata, started, start):
            y_start = start if study.initial == "equilibrium" else None
            return one_sample(
                study, index, strata, started, batch_width, y_start=y_start
            )

        records = jax.vmap(sample)(index[0], strata[0], started[0], starts[0])
        return jax.tree.map(lambda x: x[None], records)

    return jax.shard_map(
        on_device,
        mesh=mesh,
        in_specs=(P(), P("samples"), P("samples"), P("samples"), P("samples")),
        out_specs=P("samples"),
        check_vma=False,
    )(arrays, index, strata, started, starts)


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
    return _WORK_FACTOR * _trajectory_bytes(study) + _WORK_FIXED


def _trajectory_bytes(study: Study) -> int:
    """Bytes of $Y$ and $\\dot Y$ at the study's output times."""
    return 2 * len(study.ts) * study.inputs.model.n_bodies * 6 * 8


def memory_budget_for(devices) -> int:
    """The default memory budget of a chunk on `devices`: `DEVICE_MEMORY_SHARE` of
    the smallest device's memory (`Device.memory_stats()["bytes_limit"]`, which
    GPUs report) times the number of devices, or `DEFAULT_MEMORY_BUDGET` where a
    device reports none (CPUs), and never less than that."""
    limits = []
    for device in devices:
        try:
            stats = device.memory_stats()
        except Exception:  # a backend that does not implement it
            stats = None
        limit = (stats or {}).get("bytes_limit")
        if not limit:
            return DEFAULT_MEMORY_BUDGET
        limits.append(int(limit))
    if not limits:
        return DEFAULT_MEMORY_BUDGET
    per_device = int(DEVICE_MEMORY_SHARE * min(limits))
    return max(DEFAULT_MEMORY_BUDGET, per_device * len(limits))


def chunk_size_for(
    study: Study, memory_budget: int, batch_width: int, n_devices: int = 1
) -> int:
    """The chunk size: a multiple of `batch_width * n_devices` samples (the
    lanes), the largest whose memory fits in `memory_budget` bytes, of at most
    `_MAX_BATCHES_PER_CHUNK` (16) batches of lanes and at most a `MIN_CHUNKS`-th
    (1/8) of the study's batches (at least one batch). A chunk is the unit of
    storage: a killed run loses at most the chunk it was computing, so a study of
    a few batches is still cut into several chunks (1,000 samples on 128 lanes:
    8 chunks of 128).

    Per chunk: `batch_width * n_devices` samples in flight, each needing about
    `_WORK_FACTOR` times its trajectory plus `_WORK_FIXED` bytes, and every
    sample's record held three times (device result, host copy, file buffer) and
    `_CHUNK_FACTOR` times its trajectory. Raises `StudyTooLargeError` when one
    batch does not fit.
    """
    record = _chunk_bytes_per_sample(study)
    lanes = batch_width * n_devices
    in_flight = lanes * working_memory_per_sample(study)
    needed = _batch_bytes(study, lanes)
    if needed > memory_budget:
        raise StudyTooLargeError(
            f"memory_budget = {memory_budget} bytes ({format_bytes(memory_budget)}) "
            f"is too small for batch_width = {batch_width} on {n_devices} "
            f"device(s): one batch needs about {needed} bytes "
            f"({format_bytes(needed)}, {len(study.ts)} output times a sample); "
            f"raise memory_budget, or lower batch_width or the number of output times"
        )
    batches = (memory_budget - in_flight) // (lanes * record)
    share = max(1, math.ceil(study.n_samples / lanes / MIN_CHUNKS))
    batches = min(batches, _MAX_BATCHES_PER_CHUNK, share)
    return int(batches * lanes)


def default_batch_width(
    study: Study,
    memory_budget: int,
    n_devices: int = 1,
    chunk_size: int | None = None,
    platform: str = "cpu",
) -> int:
    """The samples each device integrates at once when `run_study` is given no
    `batch_width`: `DEFAULT_BATCH_WIDTH` on CPUs and `ACCELERATOR_BATCH_WIDTH` on
    other devices (`platform`, as `jax.Device.platform` names it), or fewer when
    the study (or one chunk of `chunk_size` samples) does not fill every device
    (its samples divided by `n_devices`, rounded up), halved until one batch of
    `width * n_devices` samples fits in `memory_budget` bytes (see
    `chunk_size_for`); at least 1.

    Results depend on the width at the level of rounding, so with this default
    they can differ at that level between runs on different numbers of devices;
    pass `batch_width` to `run_study` to rule that out (a store keeps its own).
    """
    samples = min(study.n_samples, chunk_size or study.n_samples)
    widest = DEFAULT_BATCH_WIDTH if platform == "cpu" else ACCELERATOR_BATCH_WIDTH
    width = min(widest, math.ceil(samples / n_devices))
    while width > 1 and _batch_bytes(study, width * n_devices) > memory_budget:
        width //= 2
    return width


def _record_bytes(study: Study) -> int:
    """Bytes of one sample's record (its outputs, status and event time)."""
    return sum(x.size * x.dtype.itemsize for x in jax.tree.leaves(_template(study)))


def _batch_bytes(study: Study, lanes: int) -> int:
    """Memory of one batch of `lanes` samples in flight: each sample's working
    memory and its record held three times (see `chunk_size_for`)."""
    return lanes * (working_memory_per_sample(study) + _chunk_bytes_per_sample(study))


def _chunk_bytes_per_sample(study: Study) -> int:
    """Memory of each sample of a chunk, integrated or not (see `chunk_size_for`):
    its record held three times and `_CHUNK_FACTOR` times its trajectory."""
    return 3 * _record_bytes(study) + _CHUNK_FACTOR * _trajectory_bytes(study)


def store_bytes(study: Study, chunk_size: int, n_chunks: int | None = None) -> int:
    """Estimated bytes on disk of `n_chunks` chunks of `chunk_size` samples
    (default: the whole study) and their records in the manifest: each sample's
    record, plus `_NPZ_BYTES_PER_VARIABLE` per variable and chunk and
    `_MANIFEST_BYTES_PER_CHUNK` per chunk."""
    total = math.ceil(study.n_samples / chunk_size)
    n = total if n_chunks is None else n_chunks
    samples = min(study.n_samples, n * chunk_size)
    variables = len(_template(study))
    per_chunk = variables * _NPZ_BYTES_PER_VARIABLE + _MANIFEST_BYTES_PER_CHUNK
    return samples * _record_bytes(study) + n * per_chunk + 64 * 1024


def host_bytes(study: Study, chunk_size: int) -> int:
    """Estimated bytes of host memory a run of `study` holds beside its chunk's
    (`chunk_size_for`): the Latin hypercube design (`4 N D` bytes, made on the
    device and copied: three times), a flag per chunk, and every sample's record
    twice (the chunks and their concatenation: `run_study` returns the whole
    study, read back from its store when it has one)."""
    strata = 3 * 4 * study.n_samples * study.n_dims if study.sampling == "lhs" else 0
    flags = math.ceil(study.n_samples / chunk_size)
    return strata + flags + 2 * study.n_samples * _record_bytes(study)


def check_needs(
    study: Study,
    chunk_size: int,
    store: Path | None,
    chunks_left: int | None = None,
    host_budget: int | None = None,
    disk_budget: int | None = None,
) -> dict[str, int]:
    """Estimate the host memory and the disk a run needs (`host_bytes`, and
    `store_bytes` of the `chunks_left` chunks still to compute) and refuse a run
    above its budget with `StudyTooLargeError` giving the estimate:
    `host_budget` (default `host_memory_budget()`, half the machine's memory) and
    `disk_budget` (default: the free space of the store's file system). Returns
    the estimates, `{"host": bytes, "disk": bytes}`."""
    what = f"the study of {study.n_samples} samples"
    disk = 0
    if store is not None:
        disk = store_bytes(study, chunk_size, chunks_left)
        limit = free_space(store) if disk_budget is None else int(disk_budget)
        if limit is not None and disk > limit:
            over = (
                f"over disk_budget = {format_bytes(limit)}"
                if disk_budget is not None
                else f"over the {format_bytes(limit)} free on its file system"
            )
            raise StudyTooLargeError(
                f"{what} needs about {format_bytes(disk)} of disk in the store {store} "
                f"({format_bytes(_record_bytes(study))} a sample), {over}; draw fewer "
                f"samples, keep fewer "
                f"outputs over time or fewer output times, or free space"
            )
    memory = host_bytes(study, chunk_size)
    budget = host_memory_budget() if host_budget is None else int(host_budget)
    if memory > budget:
        over = (
            f"over host_budget = {format_bytes(budget)}"
            if host_budget is not None
            else f"over {format_bytes(budget)}, half of this machine's memory"
        )
        raise StudyTooLargeError(
            f"{what} needs about {format_bytes(memory)} of memory for its results and "
            f"sampling design ({format_bytes(_record_bytes(study))} a sample), {over}; "
            f"draw fewer samples, or keep fewer "
            f"outputs over time or fewer output times"
        )
    return {"host": memory, "disk": disk}


def _manifest(study: Study, chunk_size: int, batch_width: int) -> dict:
    description, parts = study.describe(), study.fingerprint_parts()
    return {
        "format": FORMAT,
        "study": description,
        "fingerprint": combined_fingerprint(description, parts),
        "parts": {name: part.hexdigest() for name, part in parts.items()},
        "unverified": {
            name: part.unverified for name, part in parts.items() if part.unverified
        },
        "versions": _versions(),
        "chunk_size": chunk_size,
        "batch_width": batch_width,
        "n_chunks": math.ceil(study.n_samples / chunk_size),
        "variables": _variables(study),
        "coords": _labels(study),
        "status_codes": {s.name: int(s) for s in Status}
        | {"INVALID_SAMPLE": INVALID_SAMPLE},
    }


def _versions() -> dict[str, str]:
    """Versions of Python and of the libraries that compute a sample, draw the
    designs (SciPy's and SALib's quasi-Monte Carlo points) and estimate the
    sensitivity indices (SALib, SciPy)."""
    return {
        "python": platform.python_version(),
        "elasticoop": __version__,
        "jax": jax.__version__,
        "equinox": eqx.__version__,
        "diffrax": diffrax.__version__,
        "numpy": np.__version__,
        "scipy": importlib.metadata.version("scipy"),
        "SALib": importlib.metadata.version("SALib"),
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
    chunk_size: int | np.integer | None = None,
    batch_width: int | np.integer | None = None,
    memory_budget: int | None = None,
    devices=None,
    progress: bool = True,
    on_chunk: Callable[[int], None] | None = None,
    trust_callables: bool = False,
    host_budget: int | None = None,
    disk_budget: int | None = None,
) -> xr.Dataset:
    """Simulate every sample of `study`, chunk by chunk.

    **Arguments:**

    - `study`: a `Study`.
    - `store`: a directory for the results: created when it does not exist, used
      when it is empty, resumed when it already holds this study (complete chunks
      are kept, damaged ones computed again with a warning naming the file);
      a folder that holds other files is refused (`StoreError`), so that nothing
      of the user's is overwritten. `None` keeps results in memory. A run holds
      an exclusive lock on the store: a second run on it fails at once, naming the
      first. A store that cannot be written (a full disk, a read-only folder) is a
      `StoreError` naming the file; the chunks stored before are kept.
    - `chunk_size`: samples per chunk (default: from `memory_budget`; a resumed
      store keeps its own).
    - `batch_width`: samples integrated together by `vmap` on each device (as one
      stops, the next starts in its place). Results may depend on it at the
      level of floating-point rounding, so it is recorded, and
      a resumed store keeps its own. Default: `DEFAULT_BATCH_WIDTH` (128) on
      CPUs, `ACCELERATOR_BATCH_WIDTH` (131072) on GPUs, or fewer when the samples
      (or `chunk_size`) do not fill every device, halved until one batch fits
      `memory_budget` (`default_batch_width`).
    - `memory_budget`: bytes the chunk may use (sets the default `chunk_size`).
      Default: from the devices' memory (`memory_budget_for`): half of each
      GPU's memory, 1 GiB on CPUs.
    - `devices`: devices to shard over (default: `jax.devices()`, i.e. every
      device of every process after `jax.distributed.initialize`).
    - `progress`: show a progress bar (samples done, rate, ETA) on the first process.
    - `on_chunk`: called with the chunk number after each chunk is stored.
    - `host_budget`, `disk_budget`: bytes of host memory and of disk the study
      may take (default: half of the machine's memory, and the free space of the
      store's file system). Before the first chunk, the run estimates what it
      needs (`check_needs`: the results it returns and the sampling design; the
      store's chunks still to compute) and refuses a study above either budget
      with `StudyTooLargeError` (a `ValueError`) giving the estimate, as it
      refuses a batch above `memory_budget`.
    - `trust_callables`: resume a store even though parts of the study cannot be
      verified to be unchanged since it was started. A store is resumed only when
      every part that decides a sample's value is the same (`Study.fingerprint`:
      outputs, distributions and their inverse CDFs, `where` selectors and forces
      are compared by what they compute, see `Study.fingerprint_parts`). A Python
      function called through `jax.pure_callback` or similar cannot be compared;
      the run then refuses to resume, naming it, unless `trust_callables=True`
      says that it is unchanged.

    **Returns:** an `xarray.Dataset` with dimension `sample`: the drawn parameter
    values, the outputs, `status` (`Status` codes; -1 for a sample whose drawn
    parameters are not finite) and `event_time`. A failed sample never stops the
    study; its outputs are NaN.
    """
    if not isinstance(study, Study):
        raise ValueError(f"study must be a Study, got {type(study).__name__}")
    for name, value in (("batch_width", batch_width), ("chunk_size", chunk_size)):
        if value is not None and (
            isinstance(value, bool)
            or not isinstance(value, numbers.Integral)
            or value < 1
        ):
            raise ValueError(f"{name} must be a positive integer, got {value!r}")
    width = None if batch_width is None else int(batch_width)
    chunk = None if chunk_size is None else int(chunk_size)
    devices = list(jax.devices() if devices is None else devices)
    if not devices:
        raise ValueError("devices must name at least one device, got none")
    if memory_budget is None:
        memory_budget = memory_budget_for(devices)
    mesh = Mesh(np.array(devices), ("samples",))
    with contextlib.ExitStack() as stack:
        if store is None:
            if width is None:
                width = default_batch_width(
                    study, memory_budget, len(devices), chunk, devices[0].platform
                )
            chunk = _chunk_size(
                study, None, None, chunk, memory_budget, width, len(devices)
            )
            check_needs(study, chunk, None, host_budget=host_budget)
            manifest = _manifest(study, chunk, width)
            done = np.zeros(manifest["n_chunks"], dtype=bool)
        else:
            manifest, done = _open_store(
                study,
                store,
                stack,
                chunk,
                memory_budget,
                width,
                len(devices),
                devices[0].platform,
                trust_callables,
                (host_budget, disk_budget),
                progress,
            )
        records = _run_chunks(study, store, manifest, done, mesh, progress, on_chunk)
    if store is None:
        return to_dataset(concatenate(records), manifest)
    barrier("elasticoop-montecarlo-finished")
    return open_study(store)


def _chunk_size(
    study, store, existing, chunk_size, memory_budget, batch_width, n_devices
):
    if existing is not None:
        if chunk_size is not None and chunk_size != existing["chunk_size"]:
            raise StoreError(
                f"chunk_size = {chunk_size}, but the store {store} was started with "
                f"chunk_size = {existing['chunk_size']}; omit chunk_size to resume"
            )
        chunk_size = existing["chunk_size"]
    elif chunk_size is None:
        chunk_size = chunk_size_for(study, memory_budget, batch_width, n_devices)
    return int(chunk_size)


def _open_store(
    study,
    store,
    stack,
    chunk_size,
    memory_budget,
    batch_width,
    n_devices,
    platform,
    trust_callables,
    budgets,
    progress,
) -> tuple[dict, np.ndarray]:
    """Check the folder, lock, check the study's needs and prepare the store on
    the first process (the lock is held until `stack` closes); every process gets
    the manifest and the done chunks. A folder this run created is removed again
    when the store is refused."""
    if is_first_process():
        path = Path(store)
        created = False
        try:
            check_store_folder(path)
            created = not path.exists()
            try:
                path.mkdir(parents=True, exist_ok=True)
            except OSError as err:
                raise StoreError(
                    f"cannot use {path} as a study store: {err.strerror or err}"
                ) from None
            stack.enter_context(store_lock(path))
            existing = read_manifest(path)
            if batch_width is None:
                # a resumed store keeps its own
                batch_width = (
                    default_batch_width(
                        study, memory_budget, n_devices, chunk_size, platform
                    )
                    if existing is None
                    else int(existing["batch_width"])
                )
            chunk_size = _chunk_size(
                study, path, existing, chunk_size, memory_budget, batch_width, n_devices
            )
            n_chunks = math.ceil(study.n_samples / chunk_size)
            recorded = len(existing.get("chunks", {})) if existing else 0
            needs = check_needs(
                study, chunk_size, path, max(0, n_chunks - recorded), *budgets
            )
            manifest = _manifest(study, chunk_size, batch_width)
            manifest = prepare(path, manifest, trust_callables)
        except Exception:
            broadcast_from_first(np.zeros(3, np.int64))  # the others stop too
            stack.close()  # the lock released, its file removed
            if created:
                with contextlib.suppress(OSError):
                    path.rmdir()  # only if empty
            raise
        broadcast_from_first(np.array([1, chunk_size, batch_width], np.int64))
        done = np.zeros(manifest["n_chunks"], dtype=bool)
        done[[int(c) for c in manifest["chunks"]]] = True
        if progress:
            _say_start(study, path, manifest, done, existing is not None, needs)
    else:
        ok, chunk_size, batch_width = broadcast_from_first(
            np.zeros(3, np.int64)
        ).tolist()
        if not ok:
            raise RuntimeError(
                f"the first process could not open the study store {store} (see "
                f"its error)"
            )
        manifest = _manifest(study, chunk_size, batch_width)
        done = np.zeros(manifest["n_chunks"], dtype=bool)
    done = broadcast_from_first(done)
    barrier("elasticoop-montecarlo-prepared")
    return manifest, done


def _say_start(study, path, manifest, done, resumed: bool, needs: dict) -> None:
    """One line on stderr: the chunks of the study and the disk they need, or, for
    a resumed store, how many chunks it kept."""
    n_chunks, size = manifest["n_chunks"], manifest["chunk_size"]
    kept = int(done.sum())
    if resumed:
        samples = sum(
            min(size, study.n_samples - int(c) * size) for c in np.flatnonzero(done)
        )
        text = (
            f"resuming the study store {path}: kept {kept} of {n_chunks} chunks "
            f"({samples} of {study.n_samples} samples), {n_chunks - kept} to compute"
        )
    else:
        text = (
            f"study store {path}: {study.n_samples} samples in {n_chunks} chunk"
            f"{'' if n_chunks == 1 else 's'} of {size}, about "
            f"{format_bytes(needs['disk'])} on disk"
        )
    print(text, file=sys.stderr, flush=True)


def _run_chunks(study, store, manifest, done, mesh, progress, on_chunk) -> list[dict]:
    """Compute the chunks not `done`: stored (first process) when `store` is given,
    returned otherwise."""
    chunk_size, n_chunks = manifest["chunk_size"], manifest["n_chunks"]
    batch_width = manifest["batch_width"]
    n_devices = mesh.devices.size
    strata = lhs_strata(study)
    program = study._program_view()
    traced = _replicated(mesh, program)
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
            # every chunk as long as the first (one compilation), the padding of
            # the last one stopped at once
            padded = math.ceil(min(chunk_size, study.n_samples) / n_devices) * n_devices
            numbers = np.arange(start, start + padded)
            index = np.minimum(numbers, stop - 1)
            if study.initial == "equilibrium":
                starts = np.asarray(_sample_starts(program, index, strata[index]))
            else:
                starts = np.zeros((padded, 0))  # not used
            launches = [
                _run_batch(
                    traced,
                    mesh,
                    _global_array(mesh, index.reshape(n_devices, -1)),
                    _global_array(
                        mesh, strata[index].reshape(n_devices, padded // n_devices, -1)
                    ),
                    _global_array(mesh, (numbers < stop).reshape(n_devices, -1)),
                    _global_array(
                        mesh,
                        starts.reshape(
                            n_devices, padded // n_devices, *starts.shape[1:]
                        ),
                    ),
                    batch_width,
                )
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
                write_chunk(store, chunk, record, manifest)
            failed += int(np.sum(record["status"] != Status.SUCCESS))
            bar.update(stop - start)
            bar.set_postfix(failed=failed)
            if on_chunk is not None:
                on_chunk(chunk)
    return in_memory
