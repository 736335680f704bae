"""An exclusive lock on a study store, so that one run at a time writes to it.

The lock is `fcntl.flock` on the store's `.lock` file, which holds the holder's
process id, host, start time and command line. The kernel releases it when the
holder ends, however it ends, so a killed run never leaves a stale lock: its file
stays behind (a run ending normally removes it) and the next run takes over with a
warning naming the run that did not finish. A second run while the lock is held
fails at once with an error naming the holder, before it reads or writes anything
else in the store.
"""

import contextlib
import datetime
import json
import os
import socket
import sys
import warnings
from collections.abc import Iterator
from pathlib import Path

from .store import LOCK, StoreError


class StoreLockedError(RuntimeError):
    """The study store is in use by another run."""


@contextlib.contextmanager
def store_lock(path: str | Path) -> Iterator[None]:
    """Hold the exclusive lock on the store `path` (an existing folder) while the
    block runs; `StoreLockedError`, naming the holder, if another run holds it."""
    file = Path(path) / LOCK
    fd = _acquire(file)
    try:
        yield
    finally:
        if fd is not None:
            file.unlink(missing_ok=True)  # before the release: see `_acquire`
            os.close(fd)


def _acquire(file: Path) -> int | None:
    try:
        import fcntl
    except ImportError:  # a platform without POSIX locks
        warnings.warn(
            f"cannot lock the study store {file.parent} on this platform: two runs "
            f"on it at once would not be detected"
        )
        return None
    while True:
        try:
            fd = os.open(file, os.O_RDWR | os.O_CREAT, 0o644)
        except OSError as err:
            raise StoreError(
                f"cannot create the lock file {file} of the study store: "
                f"{err.strerror or err} [errno {err.errno}]; the store's folder must "
                f"be writable (a read-only store can be read with 'elasticoop "
                f"montecarlo summary' or open_study)"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder(fd) or "another run (starting)"
            os.close(fd)
            raise StoreLockedError(
                f"the study store {file.parent} is in use by {holder} (lock file "
                f"{file}); wait for that run to finish or stop it, or use another "
                f"folder"
            ) from None
        except OSError as err:  # a file system without locks
            os.close(fd)
            warnings.warn(
                f"cannot lock the study store {file.parent} ({err}): two runs on it "
                f"at once would not be detected"
            )
            return None
        # The previous holder removes the file before releasing it: a lock taken
        # on a removed file is no lock, so try again on the current one.
        try:
            current = os.stat(file).st_ino == os.fstat(fd).st_ino
        except FileNotFoundError:
            current = False
        if current:
            break
        os.close(fd)
    previous = _holder(fd)
    if previous is not None:
        warnings.warn(
            f"the study store {file.parent} was locked by {previous}, which ended "
            f"without releasing it (killed?); taking the lock over"
        )
    record = {
        "pid": os.getpid(),
        "host": socket.gethostname(),
        "started": datetime.datetime.now().astimezone().isoformat(timespec="seconds"),
        "command": " ".join(sys.argv),
    }
    try:
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(record).encode(), 0)
        os.fsync(fd)
    except OSError as err:  # a full disk
        os.close(fd)
        raise StoreError(
            f"cannot write the lock file {file} of the study store: "
            f"{err.strerror or err} [errno {err.errno}]; free space and run again"
        ) from None
    return fd


def _holder(fd: int) -> str | None:
    """Who holds (or held) the lock, in words; `None` for an empty lock file."""
    data = os.pread(fd, 4096, 0)
    if not data:
        return None
    try:
        record = json.loads(data)
        return (
            f"process {record['pid']} on host {record['host']} (started "
            f"{record['started']}: {record['command']})"
        )
    except (ValueError, TypeError, KeyError):
        return f"an unknown run (its lock file holds {data[:80]!r})"
