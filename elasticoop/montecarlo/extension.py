"""Extending a stored study with more samples.

A study whose sample $s$ depends only on the key and $s$ (every sampling but the
Latin hypercube, whose strata depend on the number of samples) keeps its samples
when it is given more: the store of the smaller study is then the beginning of
the larger one. `extended` accepts such a store when the study differs from the
stored one in its number of samples alone (and has more), keeping every stored
chunk that is full under both; the last chunk of the smaller study, when it was
shorter than a chunk, is computed again (it holds more samples now).
"""

from pathlib import Path

# `sampling` values whose samples depend on their number (never extended).
NOT_EXTENSIBLE = ("lhs",)


def extends(existing: dict, manifest: dict) -> bool:
    """Whether `manifest` describes the study of `existing` with more samples."""
    old, new = existing.get("study", {}), manifest["study"]
    if new.get("sampling") in NOT_EXTENSIBLE or "parts" not in existing:
        return False
    if not new["n_samples"] > old.get("n_samples", new["n_samples"]):
        return False
    others = [k for k in {**old, **new} if k != "n_samples"]
    if any(old.get(k) != new.get(k) for k in others):
        return False
    parts = set(existing["parts"]) | set(manifest["parts"])
    if any(
        existing["parts"].get(k) != manifest["parts"].get(k)
        for k in parts
        if k != "settings"  # (n_samples, key, sampling, times): the rest is above
    ):
        return False
    return all(existing[k] == manifest[k] for k in ("chunk_size", "batch_width"))


def extended(path: Path, existing: dict, manifest: dict) -> dict:
    """`existing` as the manifest of the larger study of `manifest` when it
    `extends` it (the shorter last chunk's record dropped and its file removed),
    else `existing` unchanged."""
    if not extends(existing, manifest):
        return existing
    size, n_old = existing["chunk_size"], existing["study"]["n_samples"]
    chunks = {}
    for key, record in existing["chunks"].items():
        if (int(key) + 1) * size <= n_old:
            chunks[key] = record
        else:
            (Path(path) / f"chunk-{int(key):06d}.npz").unlink(missing_ok=True)
    keep = {k: manifest[k] for k in ("study", "fingerprint", "parts", "n_chunks")}
    return existing | keep | {"chunks": chunks}
