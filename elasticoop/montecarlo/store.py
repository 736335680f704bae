"""The result store: a directory of NumPy `.npz` chunks and a JSON manifest.

    study/
      manifest.json        the study (parameters, distributions, key, times, ...)
      chunk-000000.npz     samples [0, chunk_size)
      chunk-000001.npz     samples [chunk_size, 2 chunk_size) ...

The manifest also holds the labels of the named axes (`coords`: the model's body,
coordinate and connection names, as in the trajectory export).

Each chunk is written to a hidden temporary name, flushed to disk (`fsync`) and then
renamed to its final name (`os.replace`, atomic on POSIX file systems). A chunk is
complete exactly when its final name exists, so a process killed mid-write leaves at
most a temporary file, which is never read and is removed on the next run. Every
file opens with `numpy.load`; `open_study` returns the whole study as an
`xarray.Dataset`.
"""

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

FORMAT = "elasticoop-montecarlo-npz/1"
MANIFEST = "manifest.json"
_CHUNK = re.compile(r"^chunk-(\d{6})\.npz$")
_TEMPORARY = re.compile(r"^\.chunk-\d{6}\.npz\..*\.tmp$")


def chunk_path(path: str | Path, chunk: int) -> Path:
    return Path(path) / f"chunk-{chunk:06d}.npz"


def _write_atomic(final: Path, write) -> None:
    tmp = final.parent / f".{final.name}.{os.getpid()}.tmp"
    with open(tmp, "wb") as f:
        write(f)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, final)
    dir_fd = os.open(final.parent, os.O_RDONLY)
    try:
        os.fsync(dir_fd)
    finally:
        os.close(dir_fd)


def write_chunk(path: str | Path, chunk: int, arrays: dict) -> None:
    """Write one chunk atomically (temporary file, fsync, rename)."""
    _write_atomic(chunk_path(path, chunk), lambda f: np.savez(f, **arrays))


def read_manifest(path: str | Path) -> dict | None:
    file = Path(path) / MANIFEST
    if not file.exists():
        return None
    try:
        manifest = json.loads(file.read_text())
    except json.JSONDecodeError as err:
        raise ValueError(f"{file} is not a valid manifest: {err}") from None
    if manifest.get("format") != FORMAT:
        raise ValueError(
            f"{file} has format {manifest.get('format')!r}, expected {FORMAT!r}"
        )
    return manifest


def prepare(path: str | Path, manifest: dict) -> None:
    """Create the store, or check that an existing one holds the same study and
    remove temporary files left by a killed run."""
    path = Path(path)
    existing = read_manifest(path)
    if existing is None:
        if path.exists() and any(_CHUNK.match(p.name) for p in path.iterdir()):
            raise ValueError(f"{path} holds chunks but no {MANIFEST}; use a new folder")
        path.mkdir(parents=True, exist_ok=True)
        text = json.dumps(manifest, indent=1, sort_keys=True)
        _write_atomic(path / MANIFEST, lambda f: f.write(text.encode()))
        return
    for key in ("fingerprint", "chunk_size", "batch_width"):
        if existing[key] != manifest[key]:
            differ = [
                k
                for k in manifest["study"]
                if existing["study"].get(k) != manifest["study"][k]
            ]
            detail = f" (differing entries: {', '.join(differ)})" if differ else ""
            raise ValueError(
                f"the store {path} holds another study: its {key} is "
                f"{_short(existing[key])}, this run's is {_short(manifest[key])}"
                f"{detail}. Resume with the same settings or use a new folder."
            )
    for p in path.iterdir():
        if _TEMPORARY.match(p.name):
            p.unlink(missing_ok=True)


def _short(value):
    text = str(value)
    return text if len(text) < 20 else text[:12] + "..."


def completed_chunks(path: str | Path) -> list[int]:
    """The chunk numbers whose files are complete (renamed to their final name)."""
    path = Path(path)
    if not path.exists():
        return []
    return sorted(
        int(m.group(1)) for p in path.iterdir() if (m := _CHUNK.match(p.name))
    )


def read_chunk(path: str | Path, chunk: int, manifest: dict) -> dict:
    file = chunk_path(path, chunk)
    try:
        with np.load(file) as data:
            arrays = {k: data[k] for k in data.files}
    except (OSError, ValueError) as err:
        raise ValueError(f"chunk file {file} cannot be read: {err}") from None
    size, n = manifest["chunk_size"], manifest["study"]["n_samples"]
    expected = np.arange(chunk * size, min((chunk + 1) * size, n))
    if "sample" not in arrays or not np.array_equal(arrays["sample"], expected):
        raise ValueError(f"chunk file {file} does not hold samples {expected[0]}..")
    return arrays


def to_dataset(arrays: dict, manifest: dict) -> xr.Dataset:
    """Assemble per-sample arrays (leading axis: sample) into an `xarray.Dataset`."""
    study = manifest["study"]
    variables = {}
    for name, spec in manifest["variables"].items():
        variables[name] = (("sample", *spec["dims"]), arrays[name])
    dims = [spec["dims"] for spec in manifest["variables"].values()]
    # stores written before the labels were recorded have none but `time`
    coords = axis_labels(dims, study["ts"], manifest.get("coords", {}))
    ds = xr.Dataset(variables, coords={"sample": arrays["sample"]} | coords)
    ds.attrs["study"] = json.dumps(study)
    ds.attrs["fingerprint"] = manifest["fingerprint"]
    ds.attrs["batch_width"] = manifest["batch_width"]
    ds.attrs["chunk_size"] = manifest["chunk_size"]
    ds.attrs["n_samples"] = study["n_samples"]
    ds.attrs["complete"] = int(arrays["sample"].shape[0] == study["n_samples"])
    return ds


def axis_labels(dims, ts, labels: dict) -> dict:
    """Coordinates of the named axes that occur in `dims` (a sequence of variables'
    dimension names): `time` from `ts`, the others from `labels`."""
    seen = {d for names in dims for d in names}
    coords: dict[str, Any] = {}
    if "time" in seen:
        coords["time"] = np.asarray(ts)
    for dim, values in labels.items():
        if dim in seen and dim != "time":
            coords[dim] = list(values)
    return coords


def concatenate(chunks: list[dict]) -> dict:
    return {k: np.concatenate([c[k] for c in chunks]) for k in chunks[0]}


def open_study(path: str | Path) -> xr.Dataset:
    """Open a study store as an `xarray.Dataset` (dimension `sample` first).

    Only complete chunks are read. `ds.attrs["complete"]` is 1 when every sample is
    present; the study's specification is in `json.loads(ds.attrs["study"])`.
    """
    manifest = read_manifest(path)
    if manifest is None:
        raise ValueError(f"{path} is not a study store (no {MANIFEST})")
    done = completed_chunks(path)
    if not done:
        raise ValueError(f"the study store {path} holds no complete chunk yet")
    return to_dataset(
        concatenate([read_chunk(path, c, manifest) for c in done]), manifest
    )
