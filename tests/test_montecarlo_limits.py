"""A study store is never lost and a study never starts what it cannot finish: a
folder of other files is refused, a full disk or a read-only folder is a clear
error with the stored chunks kept, and the memory and disk a study needs are
estimated and refused above their budget before the first chunk, for study
files, command-line options and the Python API. Each case failed before; the old
behaviour is quoted in its docstring."""

import errno
import os
import re

import pytest
from test_montecarlo_store import CHUNK, WIDTH, _snapshot, _study

from elasticoop import StudyFileError, load_study, montecarlo as mc
from elasticoop._cli import main
from elasticoop._examples import example_studies

SHIPPED = example_studies()["beam_lift"]


@pytest.fixture(scope="module")
def study():
    return _study()


def _run(study, store, **kwargs):
    kwargs.setdefault("progress", False)
    return mc.run_study(study, store, batch_width=WIDTH, chunk_size=CHUNK, **kwargs)


def _files(folder):
    """Every file under `folder`, relative name -> bytes."""
    return {
        str(p.relative_to(folder)): p.read_bytes()
        for p in sorted(folder.rglob("*"))
        if p.is_file()
    }


def _user_folder(tmp_path):
    folder = tmp_path / "mine"
    (folder / "summary").mkdir(parents=True)
    (folder / "summary" / "summary.json").write_text('{"my": "results"}')
    (folder / "notes.txt").write_text("keep me")
    return folder


# 1. A store is created only in a new or empty folder (or resumed in a store).


def test_the_command_line_refuses_a_folder_of_other_files(tmp_path, capsys):
    """Before: `montecarlo STUDY -o DIR` ran into DIR and overwrote its
    summary/summary.json."""
    folder = _user_folder(tmp_path)
    before = _files(folder)
    assert main(["montecarlo", str(SHIPPED), "-o", str(folder), "-q"]) == 2
    err = capsys.readouterr().err
    assert f"{folder} is not empty and holds no study store" in err
    assert "notes.txt, summary" in err and "Traceback" not in err
    assert _files(folder) == before


@pytest.mark.slow  # over 10 s
def test_run_study_refuses_a_folder_of_other_files(study, tmp_path):
    """Before: `run_study(study, DIR)` wrote its manifest and chunks among the
    user's files."""
    folder = _user_folder(tmp_path)
    before = _files(folder)
    with pytest.raises(mc.StoreError, match="holds no study store"):
        _run(study, folder)
    assert _files(folder) == before
    empty = tmp_path / "empty"
    empty.mkdir()
    ds = _run(study, empty)  # an empty folder becomes a store
    assert ds.attrs["complete"] == 1


# 2. A full disk or a folder that cannot be written: a clear error, nothing lost.


def _failing(monkeypatch, code, marker):
    """`os.fsync` failing with `code` on files whose name holds `marker`."""
    fsync = os.fsync

    def failing(fd):
        if marker in os.readlink(f"/proc/self/fd/{fd}"):
            raise OSError(code, os.strerror(code))
        return fsync(fd)

    monkeypatch.setattr(os, "fsync", failing)


@pytest.mark.skipif(not os.path.exists("/proc/self/fd"), reason="needs /proc")
@pytest.mark.slow
def test_a_full_disk_keeps_the_stored_chunks(study, tmp_path, monkeypatch, capsys):
    """Before: `OSError: [Errno 28]` from the chunk's write, without the file's
    name (the command line called it a bug in elasticoop)."""
    store = tmp_path / "study"
    _failing(monkeypatch, errno.ENOSPC, ".chunk-000001.npz")
    with pytest.raises(mc.StoreError) as info:
        _run(study, store)
    message = str(info.value)
    assert f"cannot write {store / 'chunk-000001.npz'}" in message
    assert "No space left on device" in message and "kept" in message
    # the first chunk and the manifest are whole, no temporary file is left
    assert sorted(p.name for p in store.iterdir()) == [
        "chunk-000000.npz",
        "manifest.json",
    ]
    monkeypatch.undo()
    ds = _run(study, store, progress=True)  # resumes, says what it kept
    assert ds.attrs["complete"] == 1
    assert "kept 1 of 2 chunks (4 of 8 samples), 1 to compute" in (
        capsys.readouterr().err
    )


@pytest.mark.slow  # compiles the study, as the two other slow tests here do
def test_a_read_only_store_is_a_clear_error(study, tmp_path, monkeypatch):
    """Before: `ValueError: cannot create the lock file` (the command line called
    it a bug in elasticoop); as root, permissions cannot be taken away, so the
    file system's refusal is simulated."""
    store = tmp_path / "study"
    _run(study, store)
    before = _snapshot(store)
    opener = os.open

    def read_only(path, flags, *args, **kwargs):
        if str(path).startswith(str(store)) and flags & (os.O_WRONLY | os.O_RDWR):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return opener(path, flags, *args, **kwargs)

    monkeypatch.setattr(os, "open", read_only)
    with pytest.raises(mc.StoreError, match="Read-only file system") as info:
        _run(study, store)
    assert f"lock file {store / '.lock'}" in str(info.value)
    monkeypatch.undo()
    assert _snapshot(store) == before
    assert mc.open_study(store).attrs["complete"] == 1  # still readable


# 3. What a study needs, estimated and refused above its budget before any chunk.


def test_a_study_file_time_grid_is_capped_like_a_scenario(tmp_path):
    """Before: `[time] samples = 2000000000` in a study bypassed the scenario
    files' 1 GiB cap and allocated over 8 GiB before any check."""
    text = SHIPPED.read_text(encoding="utf-8")
    text = text.replace('scenario = "beam_lift.toml"', 'scenario = "beam_lift"')
    text = text.replace("[time]\nsamples = 61", "[time]\nsamples = 2000000000")
    path = tmp_path / "big.study.toml"
    path.write_text(text)
    with pytest.raises(StudyFileError) as info:
        load_study(path)
    assert [(p.table, p.key) for p in info.value.problems] == [("[time]", "samples")]
    assert "would need 1.06 TiB for samples = 2000000000" in str(info.value)
    assert "over the limit of 1 GiB" in str(info.value)


def test_too_many_samples_are_refused_before_any_chunk(tmp_path):
    """Before: `n_samples = 10**15` ended in a `MemoryError` traceback, and
    `10**12` started a run that needed about 1.3 PB."""
    huge = _study(n_samples=10**15)
    store = tmp_path / "study"
    with pytest.raises(mc.StudyTooLargeError) as info:
        mc.run_study(huge, store, progress=False)
    assert re.search(r"10{15} samples needs about [\d.]+ PiB of disk", str(info.value))
    assert "free on its file system" in str(info.value)
    assert not store.exists()  # nothing made
    with pytest.raises(
        mc.StudyTooLargeError, match=r"needs about [\d.]+ TiB of memory for its results"
    ):
        mc.run_study(_study(n_samples=10**12), None, progress=False)
    # (the budgets of a study that fits: tests/test_montecarlo_store.py, where the
    # study is compiled already)


@pytest.mark.slow  # builds the shipped study
def test_the_command_line_refuses_a_study_too_large_for_the_disk(tmp_path, capsys):
    """Before: `--samples 1000000000000000` ended in a `MemoryError` traceback."""
    store = tmp_path / "study"
    argv = ["montecarlo", str(SHIPPED), "-o", str(store)]
    assert main([*argv, "--samples", str(10**15), "-q"]) == 2
    err = capsys.readouterr().err
    assert "the study of 1000000000000000 samples needs about" in err
    assert "of disk in the store" in err and "Traceback" not in err
    assert not store.exists()
