"""The Monte Carlo store under hostile conditions: a resumed store never mixes two
studies, a damaged store is never trusted, and two runs never write one store."""

import json
import os
import pathlib
import re
import shutil
import socket

import jax
import numpy as np
import pytest
import xarray as xr
from helpers import three_body_model

from elasticoop import montecarlo as mc

N_SAMPLES, CHUNK, WIDTH = 8, 4, 4
TS = np.linspace(0.0, 0.1, 3)
# Euler angles regular in both conventions (|sin theta| and |cos pitch| far from 0)
ANGLES = (0.1, 0.8, 0.2)


def _state():
    return np.array([[x, 0.0, 1.0, *ANGLES] for x in (0.0, -0.5, 0.5)])


def _study(
    scale=1.0,
    spread=0.1,
    lift=3.0,
    convention="zxz",
    ppf=None,
    callback=False,
    n_samples=N_SAMPLES,
):
    """Every callable a lambda or a closure: the output, the stiffness law (and its
    inverse CDF with `ppf`) and the feedback force."""
    force = np.zeros((2, 6))
    force[:, 2] = lift
    outputs = {"height": lambda traj: scale * traj.y[-1, 0, 2]}
    if callback:
        outputs["twice"] = lambda traj: jax.pure_callback(
            lambda z: 2.0 * z,
            jax.ShapeDtypeStruct((), np.float64),
            traj.y[-1, 0, 2],
            vmap_method="sequential",
        )
    law = mc.Custom(
        lambda key: 1.0 + spread * jax.random.normal(key),
        ppf=None if ppf is None else (lambda u: 1.0 + ppf * u),
    )
    return mc.Study(
        three_body_model(convention),
        _state(),
        np.zeros((3, 6)),
        TS,
        forces=lambda t, y, ydot: force,
        parameters=[mc.Parameter("k", lambda m: m.stiffness, law, relative=True)],
        outputs=outputs,
        n_samples=n_samples,
        key=3,
        sampling="random" if ppf is None else "lhs",
    )


class _Stop(Exception):
    pass


def _stop(chunk):
    raise _Stop


def _run(study, store, **kwargs):
    return mc.run_study(study, store, batch_width=WIDTH, progress=False, **kwargs)


@pytest.fixture(scope="module")
def study():
    return _study()


@pytest.fixture(scope="module")
def reference(study):
    return _run(study, None, chunk_size=CHUNK)


@pytest.fixture(scope="module")
def half_store(study, tmp_path_factory):
    """A store interrupted after its first chunk (of two)."""
    store = tmp_path_factory.mktemp("half") / "study"
    with pytest.raises(_Stop):
        _run(study, store, chunk_size=CHUNK, on_chunk=_stop)
    return store


@pytest.fixture(scope="module")
def full_store(study, reference, tmp_path_factory):
    store = tmp_path_factory.mktemp("full") / "study"
    _run(study, store, chunk_size=CHUNK)
    return store


def test_budgets_refuse_below_the_estimate_and_run_within_it(study, tmp_path):
    """`disk_budget` and `host_budget` refuse a run whose estimated needs exceed
    them, before anything is made; a run within the estimate completes and uses
    no more disk than estimated (the estimate is an upper bound)."""
    store = tmp_path / "study"
    needs = mc.check_needs(study, CHUNK, store)
    with pytest.raises(mc.StudyTooLargeError, match="over disk_budget = 100 bytes"):
        _run(study, store, chunk_size=CHUNK, disk_budget=100)
    with pytest.raises(mc.StudyTooLargeError, match="over host_budget = 100 bytes"):
        _run(study, None, chunk_size=CHUNK, host_budget=100)
    assert not store.exists()
    ds = _run(
        study,
        store,
        chunk_size=CHUNK,
        disk_budget=needs["disk"],
        host_budget=needs["host"],
    )
    used = sum(p.stat().st_size for p in store.iterdir())
    assert used <= needs["disk"]
    assert ds.attrs["complete"] == 1


def test_the_manifest_records_what_computed_the_store(full_store):
    """The versions of the libraries that draw the samples (SciPy's and SALib's
    designs), compute them and estimate sensitivity indices from them."""
    import importlib.metadata

    versions = json.loads((full_store / "manifest.json").read_text())["versions"]
    for name in ("elasticoop", "jax", "equinox", "diffrax", "numpy", "scipy", "SALib"):
        assert versions[name] == importlib.metadata.version(name), name


def _copy(store, tmp_path):
    return shutil.copytree(store, tmp_path / "study")


def _snapshot(store):
    return {p.name: p.read_bytes() for p in sorted(store.iterdir())}


def _same(ds, reference):
    assert ds.attrs["complete"] == 1
    xr.testing.assert_identical(ds.drop_attrs(), reference.drop_attrs())


# 1. A resumed store never mixes two studies.

CHANGED = {
    "output": (lambda: _study(scale=2.0), "outputs['height']"),
    "distribution": (lambda: _study(spread=0.2), "parameters['k']"),
    "feedback force": (lambda: _study(lift=3.5), "forces"),
    "rotation convention": (lambda: _study(convention="rpy"), "model"),
}
# each case builds (traces) a study of its own
SLOW_CASES = ("distribution", "feedback force", "rotation convention")


@pytest.mark.parametrize(
    "case",
    [
        pytest.param(c, marks=pytest.mark.slow) if c in SLOW_CASES else c
        for c in CHANGED
    ],
)
def test_resume_with_a_changed_part_is_refused(case, half_store, tmp_path):
    """Each change keeps every name (all lambdas, the same arrays elsewhere), so
    only what the callables compute, or a static field, tells the studies apart."""
    make, part = CHANGED[case]
    store = _copy(half_store, tmp_path)
    before = _snapshot(store)
    with pytest.raises(ValueError, match=r"holds another study") as err:
        _run(make(), store)
    assert re.search(rf"these parts differ: {re.escape(part)}\.", str(err.value))
    assert _snapshot(store) == before


@pytest.mark.slow  # builds three studies of its own
def test_inverse_cdf_is_part_of_the_fingerprint():
    studies = [_study(ppf=p) for p in (0.2, 0.2, 0.3)]
    fingerprints = [s.fingerprint() for s in studies]
    assert fingerprints[0] == fingerprints[1] != fingerprints[2]
    digests = [
        {k: d.hexdigest() for k, d in s.fingerprint_parts().items()} for s in studies
    ]
    assert digests[0] == digests[1]  # fresh lambdas of the same code
    differ = [k for k in digests[0] if digests[0][k] != digests[2][k]]
    assert differ == ["parameters['k']"]


def test_a_resumed_store_keeps_its_batch_width(study, half_store, reference, tmp_path):
    # started with WIDTH; resumed without a width (whose default, 8 samples here,
    # differs) it keeps WIDTH and so gives the same values bit for bit
    assert mc.default_batch_width(study, 2**30) == N_SAMPLES != WIDTH
    store = _copy(half_store, tmp_path)
    ran = []
    ds = mc.run_study(study, store, progress=False, on_chunk=ran.append)
    assert ran == [1] and ds.attrs["batch_width"] == WIDTH
    _same(ds, reference)


@pytest.mark.slow  # builds and compiles a study of its own
def test_the_same_study_with_fresh_lambdas_resumes(half_store, reference, tmp_path):
    store = _copy(half_store, tmp_path)
    ran = []
    ds = _run(_study(), store, on_chunk=ran.append)
    assert ran == [1]
    _same(ds, reference)


@pytest.mark.slow  # builds and compiles a study of its own
def test_an_unverifiable_callable_needs_trust_to_resume(tmp_path):
    study = _study(callback=True)
    store = tmp_path / "study"
    with pytest.raises(_Stop):
        _run(study, store, chunk_size=CHUNK, on_chunk=_stop)
    with pytest.raises(
        ValueError,
        match=r"cannot be verified .* outputs\['twice'\]: it calls the Python "
        r"function .*<lambda> through jax pure_callback.* trust_callables=True",
    ):
        _run(study, store)
    ran = []
    ds = _run(study, store, on_chunk=ran.append, trust_callables=True)
    assert ran == [1]
    np.testing.assert_array_equal(ds["twice"], 2.0 * ds["height"])


# 7. A damaged store is never trusted.


def _truncate(data):
    return data[: len(data) // 2]


def _flip(data):
    data = bytearray(data)
    data[len(data) // 2] ^= 0x01
    return bytes(data)


DAMAGE = {"truncated": _truncate, "empty": lambda data: b"", "bit flip": _flip}


@pytest.mark.parametrize("case", DAMAGE)
def test_a_damaged_chunk_is_named_and_computed_again(
    case, study, full_store, reference, tmp_path
):
    store = _copy(full_store, tmp_path)
    chunk = store / "chunk-000001.npz"
    chunk.write_bytes(DAMAGE[case](chunk.read_bytes()))
    with pytest.raises(ValueError, match=re.escape(str(chunk))):
        mc.open_study(store)
    ran = []
    with pytest.warns(UserWarning, match=rf"{re.escape(str(chunk))} is damaged"):
        ds = _run(study, store, on_chunk=ran.append)
    assert ran == [1]
    _same(ds, reference)
    _same(mc.open_study(store), reference)


def _drop(key):
    def damage(manifest):
        del manifest[key]
        return json.dumps(manifest).encode()

    return damage


MANIFEST_DAMAGE = {
    "binary": (lambda m: b"\xff\xfe\x00\x81 not text", "not UTF-8 text"),
    "a list": (lambda m: b"[1, 2]", "holds a list, not a table"),
    "missing key": (_drop("variables"), "'variables' is missing"),
    "wrong type": (
        lambda m: json.dumps(m | {"chunk_size": "four"}).encode(),
        "'chunk_size' must be of type integer",
    ),
    "bad checksum": (
        lambda m: json.dumps(m | {"chunks": {"0": {"sha256": "x", "bytes": 1}}}),
        "'chunks.0.sha256' is not a SHA-256 digest",
    ),
}


@pytest.mark.parametrize("case", MANIFEST_DAMAGE)
def test_a_damaged_manifest_is_named(case, study, full_store, tmp_path):
    store = _copy(full_store, tmp_path)
    file = store / "manifest.json"
    damage, problem = MANIFEST_DAMAGE[case]
    data = damage(json.loads(file.read_text()))
    file.write_bytes(data if isinstance(data, bytes) else data.encode())
    match = f"{re.escape(str(file))} .*{re.escape(problem)}"
    with pytest.raises(ValueError, match=match):
        mc.open_study(store)
    with pytest.raises(ValueError, match=match):
        _run(study, store)


# 8. One run at a time on a store.


def test_a_second_run_on_a_locked_store_fails_without_touching_it(
    study, reference, tmp_path
):
    store = tmp_path / "study"
    store.mkdir()
    # a lock file left by a killed run (its lock is gone with its process)
    stale = {"pid": 999_999, "host": "elsewhere", "started": "then", "command": "x"}
    (store / ".lock").write_text(json.dumps(stale))
    errors = []

    def second_run(chunk):
        # what the first run has in flight: a temporary chunk
        (store / ".chunk-000001.npz.1.tmp").write_bytes(b"in flight")
        before = _snapshot(store)
        with pytest.raises(RuntimeError, match="is in use by") as err:
            _run(study, store)
        errors.append(str(err.value))
        assert _snapshot(store) == before
        (store / ".chunk-000001.npz.1.tmp").unlink()

    with pytest.warns(UserWarning, match="locked by process 999999 on host elsewhere"):
        ds = _run(study, store, chunk_size=CHUNK, on_chunk=second_run)
    holder = f"process {os.getpid()} on host {socket.gethostname()}"
    assert len(errors) == 2 and all(f"is in use by {holder}" in e for e in errors)
    _same(ds, reference)
    assert not (store / ".lock").exists()


@pytest.mark.parametrize("sampling", ["lhs", "random"])
def test_a_latin_hypercube_store_given_more_samples_says_why_it_is_refused(sampling):
    """A store refuses a study that differs from its own (here: the number of
    samples of a study whose `extends` fails, as the other runs' do not); for a
    Latin hypercube given more samples the message says that such a store never
    extends (before: only "these parts differ: settings, n_samples")."""
    from elasticoop.montecarlo.store import _check_same_study

    def manifest(n):
        return {
            "fingerprint": f"print-{n}",
            "chunk_size": 8,
            "batch_width": 4,
            "parts": {"settings": f"settings-{n}"},
            "study": {"n_samples": n, "sampling": sampling},
        }

    with pytest.raises(mc.StoreError, match="holds another study") as err:
        _check_same_study(pathlib.Path("store"), manifest(4), manifest(6))
    message = str(err.value)
    assert "these parts differ: settings, n_samples" in message
    assert ("its store cannot be extended" in message) == (sampling == "lhs")
