"""The main job: the built-in scenario runs and its energy balance closes."""

import json
import os
import runpy
import subprocess
import sys
from pathlib import Path

import pytest

from elasticoop._cli.demo import run_default
from elasticoop._io.summary import format_summary

# What the command line's answers must not import (`check` needs JAX, equinox and
# pydantic for the scenario, optimistix and lineax to trace its static equilibrium
# the first time, and SciPy's LAPACK through JAX to run it).
HEAVY = (
    "jax",
    "equinox",
    "diffrax",
    "optimistix",
    "lineax",
    "pydantic",
    "scipy.signal",
    "scipy.stats",
    "matplotlib",
    "xarray",
    "pandas",
    "optax",
    "h5py",
)

# The balance closes to the solver's tolerance (rtol 1e-8) times the energies.
BALANCE_RTOL = 1e-6


@pytest.mark.slow
def test_default_scenario_energy_balance_closes():
    summary = run_default()
    energy = summary["energy"]
    assert energy["work_of_forces"] > 1.0  # the arms lift the beam
    assert energy["dissipated"] > 0.0
    assert energy["relative_residual"] < BALANCE_RTOL
    dz = summary["object_displacement"][2]
    assert 0.0 < dz < 0.2  # lifted, less than the arms (the beam sags in the grasps)
    assert len(summary["peak_force"]) == 2
    text = format_summary(summary)
    assert "energy balance" in text and "grasp 2" in text


def test_dash_m_entry_point_runs_the_command_line(monkeypatch, capsys):
    """`python -m elasticoop` is the command line (run here in this process)."""
    monkeypatch.setattr(sys, "argv", ["elasticoop", "--help"])
    with pytest.raises(SystemExit) as exit_:
        runpy.run_module("elasticoop", run_name="__main__")
    assert exit_.value.code == 0
    assert capsys.readouterr().out.startswith("usage: elasticoop")


@pytest.mark.slow  # a fresh process compiles the demo again
def test_python_dash_m_runs_the_demo():
    out = subprocess.run(
        [sys.executable, "-m", "elasticoop"],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert out.returncode == 0, out.stderr
    assert "peak grasp load (elastic + damping)" in out.stdout
    assert "residual" in out.stdout


@pytest.mark.slow
def test_command_line_answers_without_the_heavy_modules(tmp_path):
    """`--version` and `--help` import neither JAX nor the scientific stack, and
    `check` (which solves the scenario's static equilibrium) none of what running,
    plotting, data files or fitting need (diffrax included); a second `check`, whose
    equilibrium's traced program is stored, not even the solvers' libraries: the
    command line answers at once."""
    scenario = Path(__file__).resolve().parents[1] / "elasticoop/scenarios"
    code = f"""
import contextlib, io, json, sys
from elasticoop._cli import main
heavy = lambda: sorted(m for m in {HEAVY!r} if m in sys.modules)
with contextlib.redirect_stdout(io.StringIO()):
    codes = [main(["--version"]), main(["--help"])]
    light = heavy()
    codes.append(main(["check", {str(scenario / "beam_lift.toml")!r}]))
print(json.dumps([codes, light, heavy()]))
"""
    env = {**os.environ, "ELASTICOOP_CACHE_DIR": str(tmp_path)}
    found = []
    for _ in range(2):  # the first stores the traced equilibrium, the second loads it
        out = subprocess.run(
            [sys.executable, "-c", code],
            capture_output=True,
            text=True,
            timeout=300,
            env=env,
        )
        assert out.returncode == 0, out.stderr
        found.append(json.loads(out.stdout.strip().splitlines()[-1]))
    (codes, after_help, after_check), (_, _, after_second) = found
    assert codes == [0, 0, 0]
    assert after_help == []
    needed = {"jax", "equinox", "pydantic"}
    assert set(after_check) <= needed | {"optimistix", "lineax"}, after_check
    assert set(after_second) <= needed, after_second


def test_each_command_is_listed_with_its_own_help_line():
    """`elasticoop --help` lists each command with the help line of its module
    without importing it; the line is the one the module gives."""
    from elasticoop._cli import COMMANDS, build_parser

    (full,) = build_parser()._subparsers._group_actions
    listed = {action.dest: action.help for action in full._choices_actions}
    assert listed == COMMANDS
    (stubs,) = build_parser([])._subparsers._group_actions
    assert {a.dest: a.help for a in stubs._choices_actions} == COMMANDS
