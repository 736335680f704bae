"""The command line, end to end in temporary folders (in-process through
`main([...])`, plus one subprocess smoke test)."""

import json
import shutil
import subprocess
import sys

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from elasticoop import GIMBAL_TOL
from elasticoop._cli import _common, main
from elasticoop._examples import example_files

EXAMPLES = sorted(example_files())
EXPECTED_BODIES = {"beam_lift": 3, "hanging_object": 2, "plate_lift": 4}
PLOTS = ("coordinates.png", "elastic_wrench.png", "energy.png", "snapshots.png")

# A free body spun about a principal axis keeps its pitch rate, and reaches the RPY
# singularity (pitch = 90 deg) at t = 10 deg / (60 deg/s) = 1/6 s.
GIMBAL = """\
name = "spinning into gimbal lock"
[model]
kind = "mobile"
convention = "rpy"
gravity = 0.0
[[bodies]]
name = "disc"
mass = 1.0
inertia = [0.01, 0.01, 0.01]
[initial.disc]
position = [0.0, 0.0, 0.0]
angles = { degrees = [0.0, 80.0, 0.0] }
angle_rates = { degrees = [0.0, 60.0, 0.0] }
[time]
stop = 0.5
samples = 11
"""


@pytest.fixture(scope="module")
def examples_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("examples")
    assert main(["examples", "--copy", str(folder), "-q"]) == 0
    return folder


def test_copying_examples_keeps_edited_files_unless_overwrite(tmp_path, capsys):
    folder = tmp_path / "study"
    assert main(["examples", "--copy", str(folder), "-q"]) == 0
    # copying again over unchanged files is fine
    assert main(["examples", "--copy", str(folder), "-q"]) == 0
    edited = folder / "beam_lift.toml"
    mine = edited.read_text() + "# my change\n"
    edited.write_text(mine)
    (folder / "hanging_object_K.csv").write_text("0\n")
    (folder / "plate_lift.toml").unlink()
    capsys.readouterr()
    assert main(["examples", "--copy", str(folder)]) == 2
    err = capsys.readouterr().err
    assert "beam_lift.toml, hanging_object_K.csv" in err and "--overwrite" in err
    assert "Traceback" not in err
    # nothing was copied: the edit is kept, the missing file is still missing
    assert edited.read_text() == mine and not (folder / "plate_lift.toml").exists()
    assert main(["examples", "--copy", str(folder), "--overwrite", "-q"]) == 0
    assert edited.read_text() != mine and (folder / "plate_lift.toml").is_file()


def test_examples_are_listed_and_copied(examples_dir, capsys):
    assert EXAMPLES == sorted(EXPECTED_BODIES)
    assert main(["examples"]) == 0
    out = capsys.readouterr().out
    assert all(name in out for name in EXAMPLES)
    copied = {p.name for p in examples_dir.iterdir()}
    assert {f"{name}.toml" for name in EXAMPLES} <= copied
    assert "hanging_object_K.csv" in copied


# plate_lift starts from its equilibrium, whose solver compiles for its structure
@pytest.mark.parametrize(
    "names",
    [
        pytest.param([n for n in EXAMPLES if n != "plate_lift"], id="fast"),
        pytest.param(["plate_lift"], id="plate_lift", marks=pytest.mark.slow),
    ],
)
def test_check_accepts_every_example(examples_dir, capsys, names):
    files = [str(examples_dir / f"{name}.toml") for name in names]
    assert main(["check", *files]) == 0
    out = capsys.readouterr().out
    assert out.count("valid scenario") == len(names)
    assert main(["check", "-q", files[0]]) == 0
    assert capsys.readouterr().out == ""


def test_check_reads_a_study_file_as_a_study_file(examples_dir, capsys):
    # Before: read as a scenario, "unknown key 'scenario'", "missing table [model]"
    study = (examples_dir / "beam_lift.study.toml").read_text()
    bad = examples_dir / "bad.study.toml"
    bad.write_text(study.replace("absolute_spread = 0.1", "absolute_spread = -0.1"))
    assert main(["check", str(bad)]) == 2
    err = capsys.readouterr().err
    assert "1 problem in the study file" in err and "(got -0.1)" in err, err
    assert "unknown key" not in err and "Traceback" not in err


@pytest.mark.slow  # builds the study (it traces a run of the scenario)
def test_check_accepts_the_shipped_study(examples_dir, capsys):
    assert main(["check", str(examples_dir / "beam_lift.study.toml")]) == 0
    out = capsys.readouterr().out
    assert "valid study file 'beam lift with uncertain grasps'" in out
    assert "1000 samples (lhs), parameters: stiffness, damping, mass, kp" in out


@pytest.mark.parametrize("name", EXAMPLES)
@pytest.mark.slow
def test_run_every_example(examples_dir, tmp_path, capsys, name):
    outdir = tmp_path / "out"
    plots = [] if name == "beam_lift" else ["--no-plots"]
    code = main(["run", str(examples_dir / f"{name}.toml"), "-o", str(outdir), *plots])
    assert code == 0, capsys.readouterr().err
    out = capsys.readouterr().out
    assert "energy balance" in out and "trajectory.nc" in out
    n = EXPECTED_BODIES[name]
    with xr.open_dataset(outdir / "trajectory.nc", engine="h5netcdf") as ds:
        samples = ds.sizes["time"]
        assert ds["y"].shape == (samples, n, 6)
        assert ds["y"].dims == ("time", "body", "coordinate")
        assert ds.attrs["status"] == 0
        assert ds.attrs["scenario_file"].endswith(f"{name}.toml")
        assert np.all(np.isfinite(ds["y"].values))
        # the manipulators' forces are exported, zero on the object
        assert ds["applied_force"].dims == ds["y"].dims
        assert np.all(ds["applied_force"].values[:, 0] == 0)
        residual = np.max(np.abs(ds["energy_residual"].values))
        scale = np.max(np.abs(ds["work"].values)) + np.max(ds["dissipated"].values)
        assert residual < 1e-5 * scale  # the energy balance closes
    frame = pd.read_csv(outdir / "trajectory.csv")
    assert frame.shape[0] == samples and frame.columns[0] == "time [s]"
    summary = json.loads((outdir / "summary.json").read_text())
    assert summary["status"] == 0 and len(summary["bodies"]) == n
    assert summary["scenario_file"].endswith(f"{name}.toml")
    written = {p.name for p in outdir.iterdir()}
    assert set(PLOTS) <= written if not plots else not set(PLOTS) & written


@pytest.mark.slow
def test_hanging_object_physics_from_the_output_files(examples_dir, tmp_path):
    # Independent checks on the written data: (1) no external torque, so the yaw
    # momentum sum C_i yaw_i' (roll = pitch = 0 stay) is conserved; (2) once
    # settled, the spring carries the object's weight: z_obj - z_grasp - (-0.1)
    # = -m_obj g / k_z.
    outdir = tmp_path / "out"
    scenario = str(examples_dir / "hanging_object.toml")
    assert main(["run", scenario, "-o", str(outdir), "--no-plots", "-q"]) == 0
    with xr.open_dataset(outdir / "trajectory.nc", engine="h5netcdf") as ds:
        c = ds["inertia"].sel(principal_axis="C").values
        yaw_rate = ds["ydot"].sel(coordinate="yaw").values
        momentum = yaw_rate @ c
        np.testing.assert_allclose(momentum, momentum[0], rtol=1e-6)
        z = ds["y"].sel(coordinate="z").values
        sag = z[-1, 0] - z[-1, 1] + 0.1
        k_z = ds["K"].values[2, 2]
        np.testing.assert_allclose(sag, -0.5 * 9.81 / k_z, rtol=1e-4)


@pytest.mark.slow  # the demo simulated and plotted in full (also run by test_main)
def test_demo_runs_quietly_and_writes_outputs(tmp_path, capsys):
    assert main(["demo", "-q", "-o", str(tmp_path / "demo"), "--no-plots"]) == 2
    capsys.readouterr()  # demo has no --no-plots: a usage error
    assert main(["demo", "-q"]) == 0
    assert capsys.readouterr().out == ""


def test_help_on_every_command(capsys):
    assert main(["--help"]) == 0
    out = capsys.readouterr().out
    for command in ("run", "check", "demo", "examples", "modes"):
        assert command in out
        assert main([command, "--help"]) == 0
        assert "usage: elasticoop " + command in capsys.readouterr().out


def test_usage_errors(capsys, tmp_path):
    assert main(["run"]) == 2  # missing SCENARIO and -o
    assert "required" in capsys.readouterr().err
    assert main(["fly"]) == 2
    assert "invalid choice" in capsys.readouterr().err
    assert main(["run", str(tmp_path / "none.toml"), "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "no such scenario file" in err and "Traceback" not in err


@pytest.mark.slow
def test_simulation_stopping_early_exits_3_with_partial_results(tmp_path, capsys):
    path = tmp_path / "gimbal.toml"
    path.write_text(GIMBAL)
    outdir = tmp_path / "out"
    assert main(["run", str(path), "-o", str(outdir), "--no-plots"]) == 3
    err = capsys.readouterr().err
    assert "simulation stopped early" in err and "gimbal lock" in err
    assert len(err.strip().splitlines()) == 1  # one paragraph, no traceback
    # the body by the scenario's name, and where the partial results are
    assert "body 'disc'" in err and "body 0" not in err
    assert "partial results, from t = 0 to 0.1" in err and str(outdir) in err
    summary = json.loads((outdir / "summary.json").read_text())
    assert summary["status"] == 1
    assert summary["simulated_time"] == pytest.approx(0.15)  # last sample before
    with xr.open_dataset(outdir / "trajectory.nc", engine="h5netcdf") as ds:
        # the run stops where |cos(pitch)| = GIMBAL_TOL, at constant pitch rate
        stop = (np.arccos(GIMBAL_TOL) - np.radians(80)) / np.radians(60)
        assert ds.attrs["event_time"] == pytest.approx(stop, rel=1e-6)


def test_progress_bar_only_when_not_quiet_and_supported(monkeypatch):
    import argparse

    import diffrax

    from elasticoop import _simulate  # imported by the command line when it runs

    def simulate_with_meter(*args, progress_meter=None, **kwargs):
        pass

    monkeypatch.setattr(_common.sys.stderr, "isatty", lambda: True, raising=False)
    monkeypatch.setattr(_simulate, "simulate", simulate_with_meter)
    loud, quiet = argparse.Namespace(quiet=False), argparse.Namespace(quiet=True)
    meter = _common.progress_overrides(loud)["progress_meter"]
    assert isinstance(meter, diffrax.TqdmProgressMeter)
    assert _common.progress_overrides(quiet) == {}
    monkeypatch.setattr(_simulate, "simulate", lambda model, y, ydot, ts: None)
    assert _common.progress_overrides(loud) == {}
    # (what `montecarlo` asks of `run_study`)
    assert _common.shows_progress(loud) and not _common.shows_progress(quiet)
    monkeypatch.setattr(_common.sys.stderr, "isatty", lambda: False, raising=False)
    assert not _common.shows_progress(loud)


@pytest.mark.slow
def test_console_entry_point_in_a_subprocess(examples_dir, tmp_path):
    good = subprocess.run(
        [
            sys.executable,
            "-m",
            "elasticoop",
            "check",
            str(examples_dir / "plate_lift.toml"),
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert good.returncode == 0, good.stderr
    assert "valid scenario 'three-grasp plate lift'" in good.stdout
    bad = tmp_path / "bad.toml"
    shutil.copyfile(examples_dir / "plate_lift.toml", bad)
    bad.write_text(bad.read_text().replace("mass = 1.5", "mass = -1.5"))
    out = subprocess.run(
        [sys.executable, "-m", "elasticoop", "check", str(bad)],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 2
    assert "table [[bodies]] #1 (plate), key 'mass'" in out.stderr
    assert "Traceback" not in out.stderr


@pytest.mark.slow
def test_modes_of_the_held_beam(examples_dir, tmp_path, capsys):
    outdir = tmp_path / "modes"
    code = main(["modes", str(examples_dir / "beam_lift.toml"), "-o", str(outdir)])
    assert code == 0
    out = capsys.readouterr().out
    assert "contact bodies are held" in out and "f [Hz]" in out and "beam." in out
    text = (outdir / "modes.json").read_text()
    summary = json.loads(text, parse_constant=not_json)  # strict JSON
    freqs = np.array(summary["frequencies_hz"])
    assert freqs.shape == (6,) and np.all(np.diff(freqs) >= 0) and freqs[0] > 0
    # the layout of the shapes is stated: a row per coordinate, a column per mode;
    # the dominant coordinate of each column is the one the printed table names
    assert summary["shapes_dims"] == ["coordinate", "mode"]
    shapes, names = np.array(summary["shapes"]), summary["coordinates"]
    assert shapes.shape == (len(names), 6)
    rows = [line.split() for line in out.splitlines() if line.split()[:1] == ["1"]]
    assert names[np.argmax(np.abs(shapes[:, 0]))] == rows[-1][-1]
    assert (outdir / "modes.png").stat().st_size > 0
    assert {p.name for p in tmp_path.iterdir()} == {"modes"}  # nothing left beside


def not_json(word):
    raise ValueError(f"{word} is not JSON")


BAD_MASS = GIMBAL.replace("mass = 1.0", "mass = -1.0")


def test_internal_bug_shows_a_traceback_and_exits_1(examples_dir, monkeypatch, capsys):
    def broken(path):
        raise ValueError("internal")

    monkeypatch.setattr(_common, "load_scenario", broken)
    assert main(["check", str(examples_dir / "beam_lift.toml")]) == 1
    err = capsys.readouterr().err
    assert "Traceback" in err and "ValueError: internal" in err
    assert "internal error" in err and "bug in elasticoop" in err

    def io_bug(path):
        raise FileNotFoundError(2, "No such file or directory", "/no/such/table.dat")

    monkeypatch.setattr(_common, "load_scenario", io_bug)
    assert main(["check", str(examples_dir / "beam_lift.toml")]) == 1
    assert "Traceback" in capsys.readouterr().err


def test_bad_scenario_file_exits_2_without_traceback(tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(BAD_MASS)
    assert main(["run", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "key 'mass'" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()


def test_debug_shows_the_traceback_of_every_error(tmp_path, monkeypatch, capsys):
    path = tmp_path / "bad.toml"
    path.write_text(BAD_MASS)
    assert main(["--debug", "run", str(path), "-o", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert "Traceback" in err and "ScenarioError" in err and "key 'mass'" in err
    assert err.rstrip().splitlines()[-1].startswith("  - table")  # message last
    assert main(["--debug", "check", str(tmp_path / "none.toml")]) == 2
    assert "Traceback" in capsys.readouterr().err
    # --debug alone runs the demo, as no arguments do
    from elasticoop._cli import demo

    seen = []
    monkeypatch.setattr(demo, "execute", lambda args: seen.append(args) or 0)
    assert main(["--debug"]) == 0
    assert seen[0].command == "demo" and seen[0].debug


def test_unusable_files_and_folders_named_by_the_user_exit_2(tmp_path, capsys):
    a_file = tmp_path / "file.txt"
    a_file.write_text("")
    for target in (a_file, a_file / "sub"):  # the folder itself, or one above it
        assert main(["examples", "--copy", str(target)]) == 2
        err = capsys.readouterr().err
        assert "elasticoop examples: error:" in err and "Traceback" not in err


def test_snapshots_outside_the_time_span_exit_2_before_simulating(tmp_path, capsys):
    path = tmp_path / "gimbal.toml"
    path.write_text(GIMBAL)
    code = main(["run", str(path), "-o", str(tmp_path / "out"), "--snapshots", "9"])
    assert code == 2
    err = capsys.readouterr().err
    assert "--snapshots: 9 s lies outside" in err and "Traceback" not in err
    assert not (tmp_path / "out").exists()
    argv = ["run", str(path), "-o", str(tmp_path / "out"), "--snapshots", "9", "-2"]
    assert main(argv) == 2
    assert "--snapshots: 9 s, -2 s lie outside" in capsys.readouterr().err


def test_unusable_cache_folder_exits_2(tmp_path, monkeypatch, capsys):
    not_a_folder = tmp_path / "cache"
    not_a_folder.write_text("")
    monkeypatch.setenv("ELASTICOOP_CACHE_DIR", str(not_a_folder))
    assert main(["run", str(tmp_path / "none.toml"), "-o", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "compilation cache folder" in err and "ELASTICOOP_CACHE_DIR" in err
    assert "Traceback" not in err


def test_option_types_for_positive_values():
    import argparse

    parser = argparse.ArgumentParser()
    parser.add_argument("--tol", type=_common.positive_float)
    parser.add_argument("--count", type=_common.positive_int)
    parser.add_argument("--rtol", type=_common.fraction)
    assert parser.parse_args(["--tol", "1e-6", "--count", "2"]).tol == 1e-6
    assert parser.parse_args(["--rtol", "0.5"]).rtol == 0.5
    for bad in (
        ["--tol", "0"],
        ["--tol", "nan"],
        ["--tol", "x"],
        ["--count", "0"],
        ["--rtol", "1"],
        ["--rtol", "2"],
    ):
        with pytest.raises(SystemExit):
            parser.parse_args(bad)
