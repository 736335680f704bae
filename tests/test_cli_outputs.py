"""The command line's output folders, files and plots: written as a whole or not
at all, never mixed with an older run's files, checked before any work, strict
JSON, and the plots that apply to the scenario."""

import errno
import json
import math
import os
import pathlib
import shutil
import subprocess
import sys

import equinox as eqx
import jax.numpy as jnp
import numpy as np
import pytest

from elasticoop._cli import main, modes, run
from elasticoop._io.strict_json import strict_json

G = 9.81
STOP = 0.1

# A body on its own, falling freely from rest: no connection, no force.
LONE_BODY = f"""\
name = "lone body"
[model]
kind = "mobile"
convention = "rpy"
gravity = {G}
[[bodies]]
name = "block"
mass = 1.0
inertia = [0.01, 0.02, 0.03]
[initial.block]
position = [0.0, 0.0, 1.0]
angles = {{ degrees = [0.0, 10.0, 0.0] }}
[time]
stop = {STOP}
samples = 5
"""

# An object hanging from a held grasp on an undamped spring: 6 modes.
HANGING_PAIR = """\
name = "hanging pair"
[model]
kind = "mobile"
convention = "rpy"
gravity = 9.81
[[bodies]]
name = "object"
mass = 0.5
inertia = [1.0e-3, 2.0e-3, 3.0e-3]
[[bodies]]
name = "grasp"
mass = 0.2
inertia = [2.0e-4, 2.0e-4, 2.0e-4]
[[connections]]
bodies = ["object", "grasp"]
stiffness = [1.0e3, 1.1e3, 1.2e3, 2.0, 2.5, 3.0]
damping = [0.0, 0.0, 0.0, 0.0, 0.0, 0.0]
[initial.object]
position = [0.0, 0.0, 0.9]
angles = { degrees = [0.0, 0.0, 0.0] }
[initial.grasp]
position = [0.0, 0.0, 1.0]
angles = { degrees = [0.0, 0.0, 0.0] }
[time]
stop = 0.1
samples = 5
"""

RESULTS = {"trajectory.nc", "trajectory.csv", "summary.json"}
PLOTS = {"coordinates.png", "energy.png", "snapshots.png"}


def strict_loads(text: str):
    """`json.loads` that refuses the non-JSON words NaN, Infinity, -Infinity."""

    def refuse(word):
        raise ValueError(f"not JSON: {word}")

    return json.loads(text, parse_constant=refuse)


def not_simulated(*args, **kwargs):
    raise AssertionError("the command simulated before checking its output folder")


def siblings(folder) -> set[str]:
    """The names beside `folder` other than itself and the scenario file."""
    return {p.name for p in folder.parent.iterdir()} - {folder.name, "lone.toml"}


@pytest.fixture
def lone_body(tmp_path):
    path = tmp_path / "lone.toml"
    path.write_text(LONE_BODY)
    return path


@pytest.fixture
def previous_run(lone_body, tmp_path):
    """An output folder holding a complete earlier run (no plots)."""
    outdir = tmp_path / "out"
    assert main(["run", str(lone_body), "-o", str(outdir), "--no-plots", "-q"]) == 0
    return outdir


def contents(folder) -> dict[str, bytes]:
    return {p.name: p.read_bytes() for p in folder.iterdir()}


@pytest.mark.slow
def test_lone_body_runs_to_the_end_skipping_the_plots_that_do_not_apply(
    lone_body, tmp_path, capsys
):
    outdir = tmp_path / "out"
    assert main(["run", str(lone_body), "-o", str(outdir)]) == 0, (
        capsys.readouterr().err
    )
    out = capsys.readouterr().out
    assert "skipped elastic_wrench.png: the model has no connections" in out
    assert {p.name for p in outdir.iterdir()} == RESULTS | PLOTS
    assert not siblings(outdir)  # no staging folder left behind
    summary = strict_loads((outdir / "summary.json").read_text())
    assert summary["status"] == 0 and summary["peak_force"] == []
    # Free fall from rest: T(t) = m (g t)^2 / 2 is drawn from the gravity energy
    # with no work; the balance closes to round-off of that exchange.
    energy = summary["energy"]
    assert energy["kinetic_final"] == pytest.approx(0.5 * (G * STOP) ** 2, rel=1e-9)
    assert energy["work_of_forces"] == 0.0
    assert energy["relative_residual"] < 1e-9


def test_non_empty_output_folder_is_refused_before_simulating(
    lone_body, previous_run, monkeypatch, capsys
):
    before = contents(previous_run)
    monkeypatch.setattr(run, "simulate_scenario", not_simulated)
    assert main(["run", str(lone_body), "-o", str(previous_run)]) == 2
    err = capsys.readouterr().err
    assert f"the output folder {previous_run} is not empty" in err
    assert "--overwrite" in err and "Traceback" not in err
    assert contents(previous_run) == before


def test_overwrite_replaces_the_folder_as_a_whole(lone_body, previous_run, capsys):
    (previous_run / "energy.png").write_bytes(b"an older run's plot")
    (previous_run / "summary.json").write_text('{"scenario": "older"}')
    args = ["run", str(lone_body), "-o", str(previous_run), "--no-plots", "-q"]
    assert main([*args, "--overwrite"]) == 0, capsys.readouterr().err
    assert {p.name for p in previous_run.iterdir()} == RESULTS  # no older file left
    summary = strict_loads((previous_run / "summary.json").read_text())
    assert summary["scenario"] == "lone body"
    assert not siblings(previous_run)


def test_overwrite_never_deletes_files_it_did_not_write(
    lone_body, previous_run, monkeypatch, capsys
):
    monkeypatch.setattr(run, "simulate_scenario", not_simulated)
    (previous_run / "notes.txt").write_text("mine")
    args = ["run", str(lone_body), "--overwrite", "--no-plots", "-o"]
    assert main([*args, str(previous_run)]) == 2
    err = capsys.readouterr().err
    assert "notes.txt, which elasticoop did not write" in err
    assert (previous_run / "notes.txt").read_text() == "mine"
    # the folder holding the scenario file, or the current folder
    assert main([*args, str(lone_body.parent)]) == 2
    err = capsys.readouterr().err
    assert f"holds the scenario file ({lone_body}), which must not be" in err
    monkeypatch.chdir(previous_run)
    assert main([*args, "."]) == 2
    err = capsys.readouterr().err
    assert f"{previous_run} is the current folder ({previous_run})" in err
    assert lone_body.exists() and (previous_run / "notes.txt").exists()


def test_unusable_output_folder_exits_2_before_simulating(
    lone_body, tmp_path, monkeypatch, capsys
):
    monkeypatch.setattr(run, "simulate_scenario", not_simulated)
    a_file = tmp_path / "file.txt"
    a_file.write_text("")
    for target, message in (
        (a_file, f"the output folder {a_file} exists and is not a folder"),
        (a_file / "out", f"{a_file} is not a folder"),
        ("", "the output folder's name is empty"),
    ):
        assert main(["run", str(lone_body), "-o", str(target)]) == 2
        err = capsys.readouterr().err
        assert message in err and "Traceback" not in err
        assert len(err.strip().splitlines()) == 1


def test_a_parent_folder_without_write_permission_exits_2(
    lone_body, tmp_path, monkeypatch, capsys
):
    # The check creates (and removes) a folder where the results will go, so that
    # it holds whatever permissions, ACLs or mount options say; here creating a
    # folder in tmp_path is denied (as it would be for a user without write
    # permission there, which the tests cannot rely on being).
    real_mkdir = os.mkdir

    def mkdir(path, *args, **kwargs):
        if pathlib.Path(path).parent == tmp_path:
            raise PermissionError(errno.EACCES, "Permission denied", str(path))
        return real_mkdir(path, *args, **kwargs)

    monkeypatch.setattr(run, "simulate_scenario", not_simulated)
    monkeypatch.setattr(os, "mkdir", mkdir)
    outdir = tmp_path / "new" / "out"
    assert main(["run", str(lone_body), "-o", str(outdir)]) == 2
    err = capsys.readouterr().err
    assert f"no folder can be created in {tmp_path} (Permission denied)" in err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "failure, code, message",
    [
        (KeyboardInterrupt(), 130, "interrupted"),
        (OSError(errno.ENOSPC, "No space left on device"), 2, "could not write"),
    ],
)
def test_a_failed_write_leaves_the_previous_results_as_they_were(
    lone_body, previous_run, monkeypatch, capsys, failure, code, message
):
    from elasticoop._io import files

    before = contents(previous_run)

    def truncated_netcdf(path, data):  # killed while writing
        pathlib.Path(path).write_bytes(b"\x89HDF\r\n")
        raise failure

    monkeypatch.setattr(files, "write_bytes", truncated_netcdf)
    args = ["run", str(lone_body), "-o", str(previous_run), "--overwrite", "-q"]
    assert main(args) == code
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert contents(previous_run) == before
    assert not siblings(previous_run)


def test_summary_json_is_strict_json_with_non_finite_numbers(
    lone_body, tmp_path, monkeypatch, capsys
):
    simulate_scenario = run.simulate_scenario

    def work_not_finite(scenario, args):  # a run whose work ends in NaN
        traj, _, error = simulate_scenario(scenario, args)
        work = traj.work.at[-1].set(jnp.nan)
        return eqx.tree_at(lambda t: t.work, traj, work), math.inf, error

    monkeypatch.setattr(run, "simulate_scenario", work_not_finite)
    outdir = tmp_path / "out"
    assert main(["run", str(lone_body), "-o", str(outdir), "--no-plots"]) == 0
    assert "work of manipulator forces  +nan" in capsys.readouterr().out
    written = strict_loads((outdir / "summary.json").read_text())
    assert written["energy"]["work_of_forces"] is None
    assert written["energy"]["residual"] is None and written["wall_time"] is None
    assert written["energy"]["kinetic_final"] == pytest.approx(0.5 * (G * STOP) ** 2)


def test_strict_json_writes_null_for_every_non_finite_number():
    value = {
        "a": [1.5, math.nan, -math.inf],
        "b": (np.float64(math.inf), np.int64(3)),
        "c": {"d": np.array([[0.25, np.nan]])},
        "e": None,
        "f": "nan",
    }
    assert strict_loads(strict_json(value)) == {
        "a": [1.5, None, None],
        "b": [None, 3],
        "c": {"d": [[0.25, None]]},
        "e": None,
        "f": "nan",
    }


def test_modes_refuses_a_non_empty_output_folder_before_solving(
    tmp_path, monkeypatch, capsys
):
    scenario = tmp_path / "pair.toml"
    scenario.write_text(HANGING_PAIR)
    outdir = tmp_path / "modes"
    outdir.mkdir()
    (outdir / "modes.json").write_text("{}")

    def not_solved(*args, **kwargs):
        raise AssertionError("solved before checking the output folder")

    monkeypatch.setattr(modes, "static_equilibrium", not_solved)
    assert main(["modes", str(scenario), "-o", str(outdir)]) == 2
    err = capsys.readouterr().err
    assert "is not empty" in err and "--overwrite" in err and "Traceback" not in err
    assert contents(outdir) == {"modes.json": b"{}"}


# -- interrupted replacements, full disks (issue: outputs never lost) -------------


def hidden(folder) -> set[str]:
    """The hidden folders beside `folder` that a write into it makes."""
    return {name for name in siblings(folder) if name.startswith(f".{folder.name}.")}


def test_leftovers_of_a_run_killed_between_the_renames_are_recovered(
    lone_body, previous_run, monkeypatch, capsys
):
    # Was: SIGKILL between the two renames left no output folder; the previous
    # results survived only in .out.previous-* beside .out.partial-*, and the next
    # run left both behind (and wrote a new folder where the old one had been).
    # These are the folders that run left.
    before = contents(previous_run)
    older = previous_run.with_name(".out.previous-0123abcd")
    newer = previous_run.with_name(".out.partial-89abcdef")
    previous_run.rename(older)
    newer.mkdir()
    (newer / "trajectory.nc").write_bytes(b"\x89HDF\r\n")  # maybe incomplete
    monkeypatch.setattr(run, "simulate_scenario", not_simulated)
    assert main(["run", str(lone_body), "-o", str(previous_run), "--no-plots"]) == 2
    err = capsys.readouterr().err
    assert f"note: {previous_run} was missing after an interrupted run" in err, err
    assert "restored it from .out.previous-0123abcd: the previous results" in err
    assert "removed .out.partial-89abcdef beside" in err
    assert f"the output folder {previous_run} is not empty" in err  # then refused
    assert contents(previous_run) == before
    assert not hidden(previous_run)


def test_complete_results_of_a_killed_swap_take_the_folder_s_place(
    lone_body, previous_run, monkeypatch, capsys
):
    before = contents(previous_run)
    complete = previous_run.with_name(".out.complete-0123abcd")
    previous_run.rename(complete)
    stale = previous_run.with_name(".out.previous-89abcdef")
    stale.mkdir()
    (stale / "summary.json").write_text("{}")
    probe = previous_run.with_name(".out.probe-00000000")
    probe.mkdir()
    monkeypatch.setattr(run, "simulate_scenario", not_simulated)
    assert main(["run", str(lone_body), "-o", str(previous_run), "-q"]) == 2
    err = capsys.readouterr().err
    assert "restored it from .out.complete-0123abcd: the complete results" in err
    assert contents(previous_run) == before
    assert not hidden(previous_run)


def test_a_write_in_progress_is_never_touched_by_another_run(
    lone_body, previous_run, monkeypatch, capsys
):
    from elasticoop._io import folder

    staging = previous_run.with_name(".out.partial-0123abcd")
    staging.mkdir()
    lock = folder._lock(staging)  # as the run writing into it holds it
    if lock is None:
        pytest.skip("no file locks on this system")
    try:
        monkeypatch.setattr(run, "simulate_scenario", not_simulated)
        assert main(["run", str(lone_body), "-o", str(previous_run), "-q"]) == 2
        assert "note:" not in capsys.readouterr().err
        assert staging.is_dir()
    finally:
        os.close(lock)


def test_overwrite_swaps_the_folders_in_one_step_on_linux(
    lone_body, previous_run, monkeypatch, capsys
):
    if not os.uname().sysname == "Linux":
        pytest.skip("renameat2(RENAME_EXCHANGE) is Linux's")
    from elasticoop._io import folder

    if not folder._exchange(previous_run, previous_run):  # a no-op swap
        pytest.skip("the file system cannot swap folders")
    real_rename = os.rename

    def rename(src, dst, *args, **kwargs):
        # the output folder is never renamed away: it always exists
        assert pathlib.Path(src) != previous_run, "the output folder was moved away"
        return real_rename(src, dst, *args, **kwargs)

    monkeypatch.setattr(os, "rename", rename)
    args = ["run", str(lone_body), "-o", str(previous_run), "--no-plots", "-q"]
    assert main([*args, "--overwrite"]) == 0, capsys.readouterr().err
    assert {p.name for p in previous_run.iterdir()} == RESULTS
    assert not hidden(previous_run)


# The command line in a child process whose dying cannot take pytest with it:
# `SETUP` runs first (a fault to inject), then `elasticoop ARGS`.
CHILD = """\
import sys
{setup}
from elasticoop._cli import main
sys.exit(main(sys.argv[1:]))
"""


def run_child(setup: str, *args) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-c", CHILD.format(setup=setup), *map(str, args)],
        capture_output=True,
        text=True,
        timeout=300,
    )


KILL_BETWEEN_RENAMES = """\
import os, signal
from elasticoop._io import folder
folder._exchange = lambda a, b: False  # the two renames of other systems
real_rename = os.rename
def rename(src, dst):
    if ".complete-" in os.fspath(src):  # the output folder is renamed away
        os.kill(os.getpid(), signal.SIGKILL)
    return real_rename(src, dst)
os.rename = rename
"""


@pytest.mark.slow
def test_sigkill_between_the_renames_loses_nothing(lone_body, previous_run, capsys):
    # Was: no output folder after the kill, and the next run left the hidden
    # .out.partial-* and .out.previous-* folders behind.
    args = ["run", lone_body, "-o", previous_run, "--no-plots", "-q", "--overwrite"]
    killed = run_child(KILL_BETWEEN_RENAMES, *args)
    assert killed.returncode == -9, killed.stderr
    assert not previous_run.exists()
    assert {n.split("-")[0] for n in hidden(previous_run)} == {
        ".out.complete",
        ".out.previous",
    }
    # the next command that writes there finishes the swap the killed run began
    assert main([str(a) for a in args[:-1]]) == 2  # (then refuses: not empty)
    err = capsys.readouterr().err
    assert "the complete results of the run that was interrupted" in err, err
    assert {p.name for p in previous_run.iterdir()} == RESULTS
    assert not hidden(previous_run)


FILE_SIZE_LIMIT = """\
import resource, signal
signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # a failed write, not a signal
resource.setrlimit(resource.RLIMIT_FSIZE, (4096, 4096))
"""


@pytest.mark.slow
def test_a_failed_netcdf_write_is_exit_2_not_signal_11(lone_body, previous_run):
    # Was: HDF5 writing trajectory.nc straight to a disk that refuses the bytes
    # (here a file-size limit, which needs no privileges; a full disk fails the
    # same way) crashed the process with signal 11.
    before = contents(previous_run)
    args = ["run", lone_body, "-o", previous_run, "--no-plots", "--overwrite"]
    out = run_child(FILE_SIZE_LIMIT, *args)
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    assert f"could not write the results into {previous_run}" in out.stderr
    assert "File too large" in out.stderr and "Traceback" not in out.stderr
    assert contents(previous_run) == before
    assert not hidden(previous_run)


@pytest.fixture
def small_disk(tmp_path):
    """A 1 MiB file system (tmpfs: needs root, as CI runs); skipped where it
    cannot be mounted."""
    mount = tmp_path / "disk"
    mount.mkdir()
    if shutil.which("mount") is None or os.geteuid() != 0:
        pytest.skip("mounting a small tmpfs needs root")
    made = subprocess.run(
        ["mount", "-t", "tmpfs", "-o", "size=1m", "tmpfs", str(mount)],
        capture_output=True,
    )
    if made.returncode != 0:
        pytest.skip(f"cannot mount a tmpfs here: {made.stderr.decode()[:200]}")
    try:
        yield mount
    finally:
        subprocess.run(["umount", "-l", str(mount)], check=False)


def fill(disk, leave: int) -> None:
    """Fill `disk` up to `leave` bytes of free space."""
    free = shutil.disk_usage(disk).free
    with open(disk / "filler", "wb") as file:
        file.write(b"\0" * max(free - leave, 0))


@pytest.mark.slow
def test_a_full_disk_is_refused_before_simulating_with_the_estimate(
    lone_body, small_disk, monkeypatch, capsys
):
    # Was: simulated, then signal 11 while writing trajectory.nc.
    outdir = small_disk / "out"
    assert main(["run", str(lone_body), "-o", str(outdir), "--no-plots", "-q"]) == 0
    before = contents(outdir)
    fill(small_disk, 16 * 1024)
    from elasticoop._cli import _common

    # (checked in `simulate_scenario`, before the run's progress meter is made)
    monkeypatch.setattr(_common, "progress_overrides", not_simulated)
    args = ["run", str(lone_body), "-o", str(outdir), "--no-plots", "--overwrite"]
    assert main(args) == 2
    err = capsys.readouterr().err
    assert f"not enough free space for the results in {outdir}" in err, err
    assert "the run writes up to" in err and "trajectory.nc" in err
    assert "Traceback" not in err
    assert contents(outdir) == before and not hidden(outdir)


FREE_SPACE_UNKNOWN = """\
from elasticoop._io import files
files.free_bytes = lambda path: 2**40  # as if the disk filled up after the check
"""


@pytest.mark.slow
def test_a_disk_that_fills_while_writing_is_exit_2_not_signal_11(lone_body, small_disk):
    # Was: signal 11 from HDF5 writing trajectory.nc onto the full disk.
    outdir = small_disk / "out"
    assert main(["run", str(lone_body), "-o", str(outdir), "--no-plots", "-q"]) == 0
    before = contents(outdir)
    fill(small_disk, 8 * 1024)
    args = ["run", lone_body, "-o", outdir, "--no-plots", "--overwrite"]
    out = run_child(FREE_SPACE_UNKNOWN, *args)
    assert out.returncode == 2, (out.returncode, out.stderr[-2000:])
    assert f"could not write the results into {outdir}" in out.stderr
    assert "No space left on device" in out.stderr
    assert "Traceback" not in out.stderr
    assert contents(outdir) == before and not hidden(outdir)


def test_results_that_cannot_take_the_folder_s_place_are_kept_visibly(
    lone_body, previous_run, monkeypatch, capsys
):
    # (a folder that filled with other files while the run wrote: its results
    # were kept in a hidden .out.partial-* folder, which a later run removes)
    from elasticoop._io import folder

    check = folder.OutputFolder.check
    calls = []

    def changed_meanwhile(self):
        calls.append(1)
        if len(calls) == 2:  # the check before the results move into place
            (self.path / "notes.txt").write_text("mine")
        return check(self)

    monkeypatch.setattr(folder.OutputFolder, "check", changed_meanwhile)
    args = ["run", str(lone_body), "-o", str(previous_run), "--no-plots", "-q"]
    assert main([*args, "--overwrite"]) == 2
    err = capsys.readouterr().err
    kept = [p for p in previous_run.parent.iterdir() if ".results-" in p.name]
    assert len(kept) == 1 and f"the results are kept in {kept[0]}" in err, err
    assert {p.name for p in kept[0].iterdir()} == RESULTS
    assert (previous_run / "notes.txt").read_text() == "mine"
    monkeypatch.setattr(folder.OutputFolder, "check", check)
    (previous_run / "notes.txt").unlink()
    assert main([*args, "--overwrite"]) == 0  # a later run leaves them alone
    assert kept[0].is_dir() and not hidden(previous_run)
