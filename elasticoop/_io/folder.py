"""An output folder written as a whole: the results go into a staging folder beside
it, which takes the folder's place only once every file is written.

A run that is killed, or fails while writing, leaves the folder as it was (a
previous run's results stay complete); a run never mixes its files with those of
an older run.

The hidden folders beside the output folder `OUT`:

- `.OUT.partial-XXXXXXXX`: the results being written (locked by the run writing
  them, with `flock`, until it ends);
- `.OUT.complete-XXXXXXXX`: every result written and flushed to disk, about to
  take `OUT`'s place;
- `.OUT.previous-XXXXXXXX`: the results `OUT` held, set aside to be removed;
- `.OUT.probe-XXXXXXXX`: an empty folder made to check that `OUT` can be created.

On Linux the new results and `OUT` trade places in one atomic step
(`renameat2(RENAME_EXCHANGE)`); elsewhere, and on file systems without it, `OUT`
is first renamed to `.OUT.previous-*`, then `.OUT.complete-*` to `OUT`. A run
killed in between leaves no `OUT`: the next command that writes into `OUT`
(`OutputFolder.recover`) puts the complete results in place, or else the previous
ones back, and removes what is left over (the folders of a run still writing are
left alone), saying what it did.
"""

import contextlib
import ctypes
import dataclasses
import errno
import fnmatch
import os
import pathlib
import re
import secrets
import shutil
import sys
from collections.abc import Iterator, Mapping

try:
    import fcntl
except ImportError:  # not on Windows: the folders of a running write are not locked
    fcntl = None  # type: ignore[assignment]

# Every file the command line writes into an output folder: `--overwrite`
# replaces a folder that holds nothing else.
RESULT_FILES = frozenset(
    {
        "trajectory.nc",
        "trajectory.csv",
        "summary.json",
        "coordinates.png",
        "elastic_wrench.png",
        "energy.png",
        "snapshots.png",
        "animation.gif",
        "animation.mp4",
        "modes.json",
        "modes.png",
        "fitted_scenario.toml",
        "report.txt",
        "report.json",
        "loss_history.png",
    }
)
# ... and the files named by these patterns (one per data file of a fit).
RESULT_PATTERNS = ("fit_*.png",)


def is_result_file(name: str) -> bool:
    """Whether `name` is the name of a file the command line writes."""
    return name in RESULT_FILES or any(
        fnmatch.fnmatchcase(name, pattern) for pattern in RESULT_PATTERNS
    )


class OutputFolderError(Exception):
    """The output folder cannot take the results: it is a file, it holds files
    and replacing it was not asked for, or its parent folder is not writable.
    The message names the folder."""


# The kinds of hidden folder a write leaves beside the output folder.
LEFTOVER_KINDS = ("partial", "complete", "previous", "probe")


def _hidden_sibling(path: pathlib.Path, kind: str) -> pathlib.Path:
    """A fresh name beside `path`: `.NAME.KIND-RANDOM`."""
    return path.with_name(f".{path.name}.{kind}-{secrets.token_hex(4)}")


def _retagged(path: pathlib.Path, kind: str) -> pathlib.Path:
    """`.NAME.OLD-RANDOM` as `.NAME.KIND-RANDOM` (the same random part)."""
    stem, _, tail = path.name.rpartition(".")
    return path.with_name(f"{stem}.{kind}-{tail.rpartition('-')[2]}")


def leftovers(path: pathlib.Path) -> list[tuple[str, pathlib.Path]]:
    """`(kind, path)` of the hidden folders beside the output folder `path` that
    a write into it made (`LEFTOVER_KINDS`), the newest first."""
    pattern = re.compile(
        rf"^\.{re.escape(path.name)}\.({'|'.join(LEFTOVER_KINDS)})-[0-9a-f]{{8}}$"
    )
    try:
        names = os.listdir(path.parent)
    except OSError:
        return []
    found = []
    for name in names:
        match = pattern.match(name)
        if match is None:
            continue
        sibling = path.parent / name
        try:
            mtime = os.lstat(sibling).st_mtime_ns
        except OSError:
            continue
        found.append((mtime, match[1], sibling))
    found.sort(reverse=True)
    return [(kind, sibling) for _, kind, sibling in found]


def _lock(folder: pathlib.Path) -> int | None:
    """An open descriptor of `folder` holding an exclusive `flock` on it (released
    when it is closed, or when the process ends, however it ends); `None` where
    locks are not available. Raises `BlockingIOError` when another process holds
    the lock."""
    if fcntl is None:
        return None
    fd = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        raise
    except OSError:  # a file system without locks
        os.close(fd)
        return None
    return fd


def _unlock(fd: int | None) -> None:
    if fd is not None:
        os.close(fd)


def _in_use(folder: pathlib.Path) -> bool:
    """Whether a running process holds the lock of `folder` (`_lock`)."""
    try:
        _unlock(_lock(folder))
    except BlockingIOError:
        return True
    except OSError:
        return False
    return False


def _remove(folder: pathlib.Path) -> None:
    if folder.is_dir() and not folder.is_symlink():
        shutil.rmtree(folder)
    else:
        folder.unlink()


_RENAME_EXCHANGE = 2
_AT_FDCWD = -100


def _exchange(a: pathlib.Path, b: pathlib.Path) -> bool:
    """Swap the folders `a` and `b` in one atomic step (Linux `renameat2` with
    `RENAME_EXCHANGE`); `False` (nothing changed) where that is not available:
    another system, an old C library or kernel, or a file system without it."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        renameat2 = ctypes.CDLL(None, use_errno=True).renameat2
    except (AttributeError, OSError):
        return False
    renameat2.argtypes = [
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_int,
        ctypes.c_char_p,
        ctypes.c_uint,
    ]
    renameat2.restype = ctypes.c_int
    if renameat2(
        _AT_FDCWD, os.fsencode(a), _AT_FDCWD, os.fsencode(b), _RENAME_EXCHANGE
    ):
        code = ctypes.get_errno()
        if code in (errno.ENOSYS, errno.EINVAL, errno.ENOTSUP, errno.EOPNOTSUPP):
            return False
        raise OSError(code, os.strerror(code), str(a), str(b))
    return True


def _fsync_tree(folder: pathlib.Path) -> None:
    """Flush the files of `folder` and the folder itself to disk."""
    for entry in folder.iterdir():
        if entry.is_file() and not entry.is_symlink():
            fd = os.open(entry, os.O_RDONLY)
            try:
                os.fsync(fd)
            finally:
                os.close(fd)
    _fsync_folder(folder)


def _fsync_folder(folder: pathlib.Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:  # some file systems cannot flush a folder
        pass
    finally:
        os.close(fd)


def _nearest_existing(path: pathlib.Path) -> pathlib.Path:
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    return path


def _listing(entries: list[str], count: int = 3) -> str:
    shown = ", ".join(sorted(entries)[:count])
    return shown + (f" and {len(entries) - count} more" if len(entries) > count else "")


@dataclasses.dataclass(frozen=True)
class OutputFolder:
    """The folder a command writes its results into.

    - `path`: the folder (created with its parents if missing).
    - `overwrite`: replace the folder if it holds files; without it, a folder that
      holds files is refused. Only a folder holding nothing but result files
      (`is_result_file`) is replaced.
    - `keep`: `(path, what it is)` of files and folders that must survive (the
      scenario file, the current folder): the output folder may not be or hold
      one of them.
    """

    path: pathlib.Path
    overwrite: bool = False
    keep: tuple[tuple[pathlib.Path, str], ...] = ()

    @classmethod
    def of(
        cls,
        path: str | os.PathLike,
        overwrite: bool = False,
        keep: Mapping[str, str] | None = None,
    ) -> "OutputFolder":
        """An `OutputFolder` with absolute paths (`~` expanded, symbolic links
        resolved: a linked folder is replaced where it lies, the link kept)."""
        text = os.fsdecode(path)
        if not text.strip():
            raise OutputFolderError("the output folder's name is empty")
        kept = tuple((_absolute(name), what) for name, what in (keep or {}).items())
        return cls(_absolute(text), overwrite, kept)

    def recover(self) -> list[str]:
        """Put right what an interrupted write into the folder left beside it
        (`leftovers`); returns what was done, one sentence each (none when
        nothing was left).

        When the folder is missing, the newest complete results take its place
        (the write was killed between its two renames), or else the newest
        previous results are put back. Every other leftover is removed: results
        being written when the run stopped, results that were replaced. Nothing
        is touched while another process is writing into the folder (its
        staging folder is locked). Raises `OutputFolderError` when a leftover
        cannot be moved or removed."""
        found = leftovers(self.path)
        if not found or any(
            _in_use(p) for kind, p in found if kind in ("partial", "complete")
        ):
            return []
        done = []
        try:
            if not os.path.lexists(self.path):
                for wanted, what in (
                    (
                        "complete",
                        "the complete results of the run that was "
                        "interrupted while moving them into place",
                    ),
                    (
                        "previous",
                        "the previous results, which a run that was "
                        "interrupted had set aside",
                    ),
                ):
                    chosen = next((p for kind, p in found if kind == wanted), None)
                    if chosen is not None:
                        os.rename(chosen, self.path)
                        found = [(k, p) for k, p in found if p != chosen]
                        done.append(
                            f"{self.path} was missing after an interrupted run; "
                            f"restored it from {chosen.name}: {what}"
                        )
                        break
            if found:
                for _, p in found:
                    _remove(p)
                done.append(
                    f"removed {_listing([p.name for _, p in found])} beside "
                    f"{self.path}, left by an interrupted run"
                )
        except OSError as err:
            raise OutputFolderError(
                f"cannot put right the folders that an interrupted run left beside "
                f"the output folder {self.path} ({err}); move or remove them by hand"
            ) from err
        _fsync_folder(self.path.parent)
        return done

    def check(self) -> None:
        """Raise `OutputFolderError` unless the results can be written: the folder
        is missing, empty, or (with `overwrite`) holds only earlier results; no
        path of `keep` lies in it; and a folder can be created beside it (tried,
        then removed). Changes nothing."""
        path = self.path
        for kept, what in self.keep:
            if kept == path or path in kept.parents:
                raise OutputFolderError(
                    f"the output folder {path} {'is' if kept == path else 'holds'} "
                    f"{what} ({kept}), which must not be replaced; choose another "
                    "folder"
                )
        if os.path.lexists(path):
            if not path.is_dir():
                raise OutputFolderError(
                    f"the output folder {path} exists and is not a folder"
                )
            self._check_contents()
        self._check_writable()

    def _check_contents(self) -> None:
        try:
            entries = os.listdir(self.path)
        except OSError as err:
            raise OutputFolderError(
                f"cannot read the output folder {self.path} ({err.strerror})"
            ) from err
        if not entries:
            return
        if not self.overwrite:
            raise OutputFolderError(
                f"the output folder {self.path} is not empty (it holds "
                f"{_listing(entries)}); give --overwrite to replace it with the new "
                "results, or choose another folder"
            )
        foreign = [
            name
            for name in entries
            if not is_result_file(name) or not (self.path / name).is_file()
        ]
        if foreign:
            raise OutputFolderError(
                f"the output folder {self.path} holds {_listing(foreign)}, which "
                "elasticoop did not write; --overwrite replaces only a folder of "
                "earlier results: move those files away or choose another folder"
            )

    def _check_writable(self) -> None:
        parent = _nearest_existing(self.path.parent)
        if not parent.is_dir():
            raise OutputFolderError(
                f"cannot create the output folder {self.path}: {parent} is not a folder"
            )
        probe = _hidden_sibling(parent / self.path.name, "probe")
        try:
            os.mkdir(probe)
            os.rmdir(probe)
        except OSError as err:
            raise OutputFolderError(
                f"cannot create the output folder {self.path}: no folder can be "
                f"created in {parent} ({err.strerror})"
            ) from err

    @contextlib.contextmanager
    def writing(self) -> Iterator[pathlib.Path]:
        """A staging folder to write the results into, beside the output folder
        (locked while this process writes into it); when the block ends without
        an error it takes the output folder's place (the previous folder is
        removed as a whole), else it is removed. An `OSError` while writing is
        raised as `OutputFolderError`."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            staging = _hidden_sibling(self.path, "partial")
            os.mkdir(staging)
        except OSError as err:
            raise OutputFolderError(
                f"cannot create the output folder {self.path} ({err})"
            ) from err
        lock = None
        try:
            try:
                lock = _lock(staging)
                yield staging
            except OSError as err:
                shutil.rmtree(staging, ignore_errors=True)
                raise OutputFolderError(
                    f"could not write the results into {self.path} ({err}); the "
                    "folder was left as it was"
                ) from err
            except BaseException:
                shutil.rmtree(staging, ignore_errors=True)
                raise
            self._move_into_place(staging)
        finally:
            _unlock(lock)

    def _move_into_place(self, staging: pathlib.Path) -> None:
        try:
            _fsync_tree(staging)
            complete = _retagged(staging, "complete")
            os.rename(staging, complete)
        except OSError as err:
            shutil.rmtree(staging, ignore_errors=True)
            raise OutputFolderError(
                f"could not write the results into {self.path} ({err}); the folder "
                "was left as it was"
            ) from err
        try:
            self.check()  # the folder may have changed while the results were made
        except OutputFolderError as err:
            kept = self._keep(complete)
            raise OutputFolderError(f"{err} (the results are kept in {kept})") from err
        previous = None
        try:
            if os.path.lexists(self.path) and _exchange(complete, self.path):
                # done: the old results are at `complete`'s name, to be removed
                previous = complete
            else:
                if os.path.lexists(self.path):
                    previous = _retagged(complete, "previous")
                    os.rename(self.path, previous)
                try:
                    os.rename(complete, self.path)
                except OSError:
                    if previous is not None:
                        os.rename(previous, self.path)
                    raise
        except OSError as err:
            kept = self._keep(complete)
            raise OutputFolderError(
                f"could not move the results into {self.path} ({err}); the results "
                f"are kept in {kept}"
            ) from err
        _fsync_folder(self.path.parent)
        if previous is not None:
            shutil.rmtree(previous, ignore_errors=True)

    def _keep(self, complete: pathlib.Path) -> pathlib.Path:
        """Give results that could not take the folder's place a name beside it
        that no later write removes (`OUT.results-XXXXXXXX`); returns where they
        are."""
        kept = self.path.with_name(f"{self.path.name}.results-{complete.name[-8:]}")
        try:
            os.rename(complete, kept)
        except OSError:
            return complete
        return kept


def _absolute(text: str) -> pathlib.Path:
    return pathlib.Path(os.path.realpath(os.path.expanduser(text)))
