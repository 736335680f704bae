"""The result store: a directory of NumPy `.npz` chunks and a JSON manifest.

    study/
      manifest.json        the study (parameters, distributions, key, times, ...),
                           its fingerprint and the SHA-256 of every chunk written
      chunk-000000.npz     samples [0, chunk_size)
      chunk-000001.npz     samples [chunk_size, 2 chunk_size) ...
      .lock                while a run writes to the store (see `lock`)

The manifest also holds the labels of the named axes (`coords`: the model's body,
coordinate and connection names, as in the trajectory export).

Each chunk is written to a hidden temporary name and flushed to disk (`fsync`);
its SHA-256 and size are then recorded in the manifest (itself replaced
atomically), and the chunk is renamed to its final name (`os.replace`, atomic on
POSIX file systems). A chunk is complete when its final name exists and its bytes
match the recorded checksum. A process killed mid-write leaves at most a temporary
file, which is never read and is removed on the next run. A chunk damaged later
(truncated, emptied, altered) is never trusted: `open_study` refuses it, naming the
file, and `run_study` recomputes it with a warning naming the file. Every file
opens with `numpy.load`; `open_study` returns the whole study as an
`xarray.Dataset`.
"""

import contextlib
import hashlib
import io
import json
import os
import re
import warnings
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from .extension import extended

FORMAT = "elasticoop-montecarlo-npz/2"
# Stores written before the checksums and the parts' digests were recorded: they
# are read (without verification) but never resumed.
FORMAT_V1 = "elasticoop-montecarlo-npz/1"
MANIFEST = "manifest.json"
_CHUNK = re.compile(r"^chunk-(\d{6})\.npz$")
_TEMPORARY = re.compile(r"^\.(chunk-\d{6}\.npz|manifest\.json)\..*\.tmp$")
_SHA256 = re.compile(r"^[0-9a-f]{64}$")
# What a damaged `.npz` file raises in `numpy.load` or when an entry is read.
_UNREADABLE = (OSError, ValueError, EOFError, KeyError, zipfile.BadZipFile)


class StoreError(ValueError):
    """A study store cannot be used: its manifest or a chunk is damaged, it holds
    another study, it holds no results yet, its folder holds other files, or it
    cannot be written (a full disk, a read-only folder). The message names the
    file."""


LOCK = ".lock"  # the lock file of a run (see `lock`)


def check_store_folder(path: str | Path) -> None:
    """Refuse a folder that cannot become or be a study store: a file, or an
    existing folder that holds files but no study store (a store is created only
    in a new or empty folder, so that no file of the user's is ever overwritten;
    the lock file and the temporary files of a run killed before its manifest was
    written are allowed)."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise StoreError(f"the study store {path} exists and is not a folder")
    if not path.is_dir() or (path / MANIFEST).exists():
        return
    try:
        others = sorted(
            p.name
            for p in path.iterdir()
            if p.name != LOCK and not _TEMPORARY.match(p.name)
        )
    except OSError as err:
        raise StoreError(f"cannot read the folder {path}: {err.strerror}") from None
    if others:
        shown = ", ".join(others[:3]) + (
            f" and {len(others) - 3} more" if len(others) > 3 else ""
        )
        raise StoreError(
            f"{path} is not empty and holds no study store (no {MANIFEST}): it holds "
            f"{shown}. A study store is created only in a new or empty folder, so "
            f"that no other file is overwritten: give a new folder"
        )


def _cannot_write(file: Path, err: OSError) -> StoreError:
    """The `StoreError` of a write into the store that failed (a full disk, a
    read-only folder, no permission), naming the file."""
    reason = err.strerror or str(err)
    return StoreError(
        f"cannot write {file}: {reason} [errno {err.errno}]. The results stored so "
        f"far are kept; free space or make the folder writable, then run the same "
        f"command again to resume"
    )


def chunk_path(path: str | Path, chunk: int) -> Path:
    return Path(path) / f"chunk-{chunk:06d}.npz"


def _write_temporary(final: Path, data: bytes) -> Path:
    """`data` in a hidden temporary file beside `final`, flushed to disk; on a
    failure (a full disk, a read-only folder) the temporary file is removed and a
    `StoreError` names `final`."""
    tmp = final.parent / f".{final.name}.{os.getpid()}.tmp"
    try:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise _cannot_write(final, err) from None
    return tmp


def _publish(tmp: Path, final: Path) -> None:
    try:
        os.replace(tmp, final)
        dir_fd = os.open(final.parent, os.O_RDONLY)
        try:
            os.fsync(dir_fd)
        finally:
            os.close(dir_fd)
    except OSError as err:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise _cannot_write(final, err) from None


def _write_atomic(final: Path, data: bytes) -> None:
    _publish(_write_temporary(final, data), final)


def write_manifest(path: str | Path, manifest: dict) -> None:
    text = json.dumps(manifest, indent=1, sort_keys=True)
    _write_atomic(Path(path) / MANIFEST, text.encode())


def write_chunk(path: str | Path, chunk: int, arrays: dict, manifest: dict) -> None:
    """Write one chunk: a temporary file (fsynced), its checksum recorded in
    `manifest` (rewritten atomically), then the rename to its final name."""
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    data = buffer.getvalue()
    final = chunk_path(path, chunk)
    tmp = _write_temporary(final, data)
    record = {"sha256": hashlib.sha256(data).hexdigest(), "bytes": len(data)}
    try:
        chunks = manifest["chunks"] | {str(chunk): record}
        write_manifest(path, manifest | {"chunks": chunks})
    except StoreError:
        with contextlib.suppress(OSError):
            tmp.unlink(missing_ok=True)
        raise
    manifest["chunks"][str(chunk)] = record
    _publish(tmp, final)


def read_manifest(path: str | Path) -> dict | None:
    """The store's manifest (checked: a damaged one raises a `ValueError` naming
    the file and the entry), or `None` when there is none."""
    file = Path(path) / MANIFEST
    if not file.exists():
        return None
    try:
        manifest = json.loads(file.read_bytes().decode("utf-8"))
    except OSError as err:
        raise StoreError(f"{file} cannot be read: {err}") from None
    except UnicodeDecodeError as err:
        raise StoreError(f"{file} is damaged: it is not UTF-8 text ({err})") from None
    except json.JSONDecodeError as err:
        raise StoreError(f"{file} is not a valid manifest: {err}") from None
    _check_manifest(manifest, file)
    return manifest


def _check_manifest(manifest: Any, file: Path) -> None:
    def fail(problem: str):
        raise StoreError(f"{file} is damaged or not a study manifest: {problem}")

    def entry(table: dict, key: str, kind: type | tuple[type, ...], where: str = ""):
        if key not in table:
            fail(f"{where}{key!r} is missing")
        value = table[key]
        if not isinstance(value, kind) or isinstance(value, bool):
            fail(f"{where}{key!r} must be of type {_kind(kind)}, got {value!r:.60}")
        return value

    if not isinstance(manifest, dict):
        fail(f"it holds a {type(manifest).__name__}, not a table")
    form = entry(manifest, "format", str)
    if form not in (FORMAT, FORMAT_V1):
        fail(f"format {form!r} is not {FORMAT!r}")
    study = entry(manifest, "study", dict)
    n_samples = entry(study, "n_samples", int, "study.")
    entry(study, "ts", list, "study.")
    entry(manifest, "fingerprint", str)
    for key in ("chunk_size", "batch_width"):
        if entry(manifest, key, int) < 1:
            fail(f"{key!r} must be a positive integer, got {manifest[key]}")
    if n_samples < 1:
        fail(f"'study.n_samples' must be a positive integer, got {n_samples}")
    n_chunks = -(-n_samples // manifest["chunk_size"])
    if entry(manifest, "n_chunks", int) != n_chunks:
        fail(f"'n_chunks' is {manifest['n_chunks']}, but the study has {n_chunks}")
    for name, spec in entry(manifest, "variables", dict).items():
        if not isinstance(spec, dict):
            fail(f"'variables.{name}' must be a table, got {spec!r:.60}")
        entry(spec, "dims", list, f"variables.{name}.")
        entry(spec, "shape", list, f"variables.{name}.")
    if not isinstance(manifest.get("coords", {}), dict):
        fail(f"'coords' must be a table, got {manifest['coords']!r:.60}")
    if form == FORMAT_V1:
        return
    entry(manifest, "parts", dict)
    entry(manifest, "unverified", dict)
    for key, record in entry(manifest, "chunks", dict).items():
        where = f"chunks.{key}."
        if not (key.isdigit() and int(key) < n_chunks):
            fail(f"'chunks' has an entry {key!r}, not a chunk number below {n_chunks}")
        if not isinstance(record, dict):
            fail(f"'chunks.{key}' must be a table, got {record!r:.60}")
        if not _SHA256.match(entry(record, "sha256", str, where)):
            fail(f"'{where}sha256' is not a SHA-256 digest: {record['sha256']!r:.80}")
        entry(record, "bytes", int, where)


def _kind(kind) -> str:
    kinds = kind if isinstance(kind, tuple) else (kind,)
    names = {"dict": "table", "list": "list", "int": "integer", "str": "string"}
    return " or ".join(names.get(k.__name__, k.__name__) for k in kinds)


def prepare(path: str | Path, manifest: dict, trust_callables: bool = False) -> dict:
    """Create the store, or check that an existing one holds the same study,
    verify its chunks and remove temporary files left by a killed run.

    Returns the manifest of the run: `manifest` with the records of the existing
    store's intact chunks (a damaged or unrecorded chunk file is removed, with a
    warning naming it, so that the run computes it again)."""
    path = Path(path)
    existing = read_manifest(path)
    manifest = manifest | {"chunks": {}}
    if existing is None:
        if any(_CHUNK.match(p.name) for p in path.iterdir()):
            raise StoreError(f"{path} holds chunks but no {MANIFEST}; use a new folder")
        write_manifest(path, manifest)
        return manifest
    file = path / MANIFEST
    if existing["format"] != FORMAT:
        raise StoreError(
            f"the store {path} was written by an earlier version of elasticoop "
            f"({file} has format {existing['format']!r}), which recorded neither "
            f"checksums of the chunks nor digests of the outputs, distributions and "
            f"forces: open it with open_study, but resume into a new folder"
        )
    existing = extended(path, existing, manifest)  # more samples of the same study
    _check_same_study(path, existing, manifest)
    recorded = existing["chunks"]
    if 0 < len(recorded) < manifest["n_chunks"] and not trust_callables:
        _check_verified(path, manifest)
    for p in path.iterdir():
        if _TEMPORARY.match(p.name):
            _remove(p)
    for key, record in sorted(recorded.items(), key=lambda kv: int(kv[0])):
        chunk = chunk_path(path, int(key))
        problem = _damage(chunk, record)
        if problem is None:
            manifest["chunks"][key] = record
        else:
            warnings.warn(f"chunk file {chunk} {problem}; it is computed again")
            _remove(chunk)
    for p in sorted(path.iterdir()):
        if (m := _CHUNK.match(p.name)) and str(int(m.group(1))) not in recorded:
            warnings.warn(
                f"chunk file {p} is not recorded in {file}, so it cannot be "
                f"verified; it is computed again"
            )
            _remove(p)
    write_manifest(path, manifest)
    return manifest


def _remove(file: Path) -> None:
    try:
        file.unlink(missing_ok=True)
    except OSError as err:
        raise StoreError(
            f"cannot remove {file} from the study store: {err.strerror}; make the "
            f"folder writable and run again"
        ) from None


def _check_same_study(path: Path, existing: dict, manifest: dict) -> None:
    for key in ("fingerprint", "chunk_size", "batch_width"):
        if existing[key] == manifest[key]:
            continue
        detail = ""
        if key == "fingerprint":
            parts, before = manifest["parts"], existing["parts"]
            differ = [k for k in {**before, **parts} if before.get(k) != parts.get(k)]
            differ += [
                k
                for k in manifest["study"]
                if existing["study"].get(k) != manifest["study"][k]
                and k not in ("parameters", "outputs", "inputs_sha256")
            ]
            if differ:
                detail = f"; these parts differ: {', '.join(dict.fromkeys(differ))}"
            detail += _latin_hypercube_grown(existing, manifest)
            detail += _version_change(existing, manifest)
        raise StoreError(
            f"the store {path} holds another study: its {key} is "
            f"{_short(existing[key])}, this run's is {_short(manifest[key])}"
            f"{detail}. Resume with the same settings or use a new folder."
        )


def _latin_hypercube_grown(existing: dict, manifest: dict) -> str:
    """Why a Latin hypercube study given more samples is not extended (every
    other sampling is: `extension.py`)."""
    old, new = existing.get("study", {}), manifest["study"]
    grown = new.get("n_samples", 0) > old.get("n_samples", new.get("n_samples", 0))
    if new.get("sampling") != "lhs" or old.get("sampling") != "lhs" or not grown:
        return ""
    return (
        " (a Latin hypercube's strata, and so all its samples, depend on their "
        "number: its store cannot be extended to more samples; run the larger "
        "study in a new folder, or sample by another method, whose stores extend)"
    )


def _version_change(existing: dict, manifest: dict) -> str:
    before, now = existing.get("versions", {}), manifest.get("versions", {})
    changed = [
        f"{name} {before[name]} -> {now[name]}"
        for name in now
        if name in before and before[name] != now[name]
    ]
    if not changed:
        return ""
    return (
        f" (the libraries changed since the store was started: "
        f"{', '.join(changed)}, which can change them too)"
    )


def _check_verified(path: Path, manifest: dict) -> None:
    unverified = manifest["unverified"]
    if not unverified:
        return
    listed = "; ".join(
        f"{part}: {', '.join(reasons)}" for part, reasons in unverified.items()
    )
    raise StoreError(
        f"cannot resume the store {path}: these parts of the study cannot be "
        f"verified to be unchanged since the store was started: {listed}. Pass "
        f"trust_callables=True to run_study if you are sure they are unchanged, or "
        f"use a new folder."
    )


def _damage(file: Path, record: dict) -> str | None:
    """What is wrong with a chunk file against its manifest record, in words;
    `None` when it is intact."""
    try:
        data = file.read_bytes()
    except FileNotFoundError:
        return "is missing (a run stopped while writing it, or it was removed)"
    except OSError as err:
        return f"cannot be read ({err})"
    return _mismatch(data, record)


def _mismatch(data: bytes, record: dict) -> str | None:
    if len(data) != record["bytes"]:
        if not data:
            what = "empty"
        else:
            what = "truncated" if len(data) < record["bytes"] else "too long"
        return (
            f"is damaged ({what}: {len(data)} bytes, the manifest records "
            f"{record['bytes']})"
        )
    if hashlib.sha256(data).hexdigest() != record["sha256"]:
        return "is damaged (its SHA-256 differs from the one in the manifest)"
    return None


def _short(value):
    text = str(value)
    return text if len(text) < 20 else text[:12] + "..."


def completed_chunks(path: str | Path, manifest: dict) -> list[int]:
    """The chunk numbers whose files are complete: renamed to their final name
    (and, in a store with checksums, recorded in `manifest`)."""
    path = Path(path)
    if not path.exists():
        return []
    present = sorted(
        int(m.group(1)) for p in path.iterdir() if (m := _CHUNK.match(p.name))
    )
    if manifest["format"] == FORMAT_V1:
        return present
    return [c for c in present if str(c) in manifest["chunks"]]


def read_chunk(path: str | Path, chunk: int, manifest: dict) -> dict:
    """The arrays of a chunk, verified against its checksum (stores with
    checksums) and against the manifest's samples and variables."""
    file = chunk_path(path, chunk)
    try:
        data = file.read_bytes()
    except OSError as err:
        raise StoreError(f"chunk file {file} cannot be read: {err}") from None
    record = manifest.get("chunks", {}).get(str(chunk))
    if record is not None and (problem := _mismatch(data, record)) is not None:
        raise StoreError(
            f"chunk file {file} {problem}; run run_study on this store again to "
            f"compute it anew"
        )
    try:
        with np.load(io.BytesIO(data)) as npz:
            arrays = {k: npz[k] for k in npz.files}
    except _UNREADABLE as err:
        raise StoreError(
            f"chunk file {file} cannot be read ({type(err).__name__}: {err})"
        ) from None
    size, n = manifest["chunk_size"], manifest["study"]["n_samples"]
    expected = np.arange(chunk * size, min((chunk + 1) * size, n))
    if "sample" not in arrays or not np.array_equal(arrays["sample"], expected):
        raise StoreError(f"chunk file {file} does not hold samples {expected[0]}..")
    for name, spec in manifest["variables"].items():
        shape = (len(expected), *spec["shape"])
        if name not in arrays or arrays[name].shape != shape:
            got = arrays[name].shape if name in arrays else "nothing"
            raise StoreError(
                f"chunk file {file} does not hold the variable {name!r} of shape "
                f"{shape}: it holds {got}"
            )
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

    Only complete chunks are read, each verified against the checksum the manifest
    records (a damaged chunk raises a `ValueError` naming the file; running
    `run_study` on the store again computes it anew). `ds.attrs["complete"]` is 1
    when every sample is present; the study's specification is in
    `json.loads(ds.attrs["study"])`.
    """
    manifest = read_manifest(path)
    if manifest is None:
        raise StoreError(f"{path} is not a study store (no {MANIFEST})")
    done = completed_chunks(path, manifest)
    present = completed_chunks(path, manifest | {"format": FORMAT_V1})
    if len(present) != len(done):
        # a run may have recorded chunks since the manifest was read
        manifest = read_manifest(path) or manifest
        done = completed_chunks(path, manifest)
        for chunk in present:
            if chunk not in done:
                raise StoreError(
                    f"chunk file {chunk_path(path, chunk)} is not recorded in "
                    f"{Path(path) / MANIFEST}, so it cannot be verified; run run_study "
                    f"on this store again to compute it anew"
                )
    if not done:
        raise StoreError(f"the study store {path} holds no complete chunk yet")
    return to_dataset(
        concatenate([read_chunk(path, c, manifest) for c in done]), manifest
    )
