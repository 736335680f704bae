"""The main job: the built-in scenario runs and its energy balance closes."""

import runpy
import subprocess
import sys

import pytest

from elasticoop._cli.demo import run_default
from elasticoop._io.summary import format_summary

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
