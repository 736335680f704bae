"""What a study may take of the machine: the budgets of host memory and disk that
`run_study` checks its estimates against before the first chunk, and the error
that refuses a study above them.

- host memory: half of the machine's physical memory (`host_memory_budget`), or
  the `host_budget` given to `run_study`;
- disk: the free space of the file system that holds the store (`free_space`), or
  the `disk_budget` given to `run_study`;
- the device memory of one chunk: `memory_budget` (see `execution`).
"""

import os
from pathlib import Path

# Share of the machine's physical memory a study's host arrays may take.
HOST_MEMORY_SHARE = 0.5
# Where the machine does not report its memory.
FALLBACK_HOST_MEMORY = 4 * 2**30


class StudyTooLargeError(ValueError):
    """A study needs more memory or disk than its budget: the message gives the
    estimate, the budget and what to change. Raised before any sample is run."""


def host_memory_budget() -> int:
    """`HOST_MEMORY_SHARE` of the machine's physical memory (`os.sysconf`), or of
    `FALLBACK_HOST_MEMORY` where it is not reported."""
    try:
        total = os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        total = 0
    if total <= 0:
        total = FALLBACK_HOST_MEMORY
    return int(HOST_MEMORY_SHARE * total)


def free_space(path: str | Path) -> int | None:
    """Free bytes of the file system that holds `path` (or its nearest existing
    folder); `None` where it cannot be told."""
    path = Path(path).absolute()
    while not path.exists() and path.parent != path:
        path = path.parent
    try:
        usage = os.statvfs(path)
    except (OSError, AttributeError):
        return None
    return usage.f_bavail * usage.f_frsize
