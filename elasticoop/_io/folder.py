"""An output folder written as a whole: the results go into a staging folder beside
it, which takes the folder's place only once every file is written.

A run that is killed, or fails while writing, leaves the folder as it was (a
previous run's results stay complete); a run never mixes its files with those of
an older run.
"""

import contextlib
import dataclasses
import fnmatch
import os
import pathlib
import secrets
import shutil
from collections.abc import Iterator, Mapping

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


def _hidden_sibling(path: pathlib.Path, kind: str) -> pathlib.Path:
    """A fresh name beside `path`: `.NAME.KIND-RANDOM`."""
    return path.with_name(f".{path.name}.{kind}-{secrets.token_hex(4)}")


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
        """A staging folder to write the results into, beside the output folder;
        when the block ends without an error it takes the output folder's place
        (the previous folder is removed as a whole), else it is removed. An
        `OSError` while writing is raised as `OutputFolderError`."""
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            staging = _hidden_sibling(self.path, "partial")
            os.mkdir(staging)
        except OSError as err:
            raise OutputFolderError(
                f"cannot create the output folder {self.path} ({err})"
            ) from err
        try:
            yield staging
        except OSError as err:
            shutil.rmtree(staging, ignore_errors=True)
            raise OutputFolderError(
                f"could not write the results into {self.path} ({err}); the folder "
                "was left as it was"
            ) from err
        except BaseException:
            shutil.rmtree(staging, ignore_errors=True)
            raise
        self._move_into_place(staging)

    def _move_into_place(self, staging: pathlib.Path) -> None:
        kept_in = f"the results are kept in {staging}"
        try:
            self.check()  # the folder may have changed while the results were made
        except OutputFolderError as err:
            raise OutputFolderError(f"{err} ({kept_in})") from err
        previous = None
        try:
            if os.path.lexists(self.path):
                if os.listdir(self.path):
                    previous = _hidden_sibling(self.path, "previous")
                    os.rename(self.path, previous)
                else:
                    os.rmdir(self.path)
            try:
                os.rename(staging, self.path)
            except OSError:
                if previous is not None:
                    os.rename(previous, self.path)
                raise
        except OSError as err:
            raise OutputFolderError(
                f"could not move the results into {self.path} ({err}); {kept_in}"
            ) from err
        if previous is not None:
            shutil.rmtree(previous, ignore_errors=True)


def _absolute(text: str) -> pathlib.Path:
    return pathlib.Path(os.path.realpath(os.path.expanduser(text)))
