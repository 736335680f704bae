"""Monte Carlo studies from study files and the command line: the study file's
validation, the `Study` it builds, and `elasticoop montecarlo` run, resumed,
refused and summarised on the shipped study at small size."""

import importlib.resources
import json
import re

import numpy as np
import pytest
from helpers import readme_command

from elasticoop import StudyFileError, load_study, montecarlo as mc
from elasticoop._cli import main
from elasticoop._examples import example_files, example_studies, load_example

SHIPPED = example_studies()["beam_lift"]


def _write(tmp_path, text, name="study.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


BAD = """\
scenario = "beam_lift"
colour = "red"

[sampling]
samples = 0
method = "sobol"

[[parameters]]
quantity = "stiffness"
connections = ["beam-middle"]
distribution = "lognormal"
relative_spread = 0.1

[[parameters]]
quantity = "stiffness"
distribution = "normal"
relative_spread = 0.1

[[parameters]]
quantity = "mass"
distribution = "normal"
relative_spread = 0.3

[[parameters]]
quantity = "damping"
distribution = "lognormal"
absolute_spread = 5.0

[[parameters]]
quantity = "kp"
axes = ["x", "y"]
distribution = "uniform"
relative_spread = [0.1, 0.2, 0.3]

[[parameters]]
quantity = "gravity"
distribution = "uniform"
absolute_spread = -0.1

[[outputs]]
quantity = "object_pose"
thresholds = [1.0]

[sensitivity]
outputs = ["object_pose"]
"""


def test_a_study_file_reports_every_problem_at_once(tmp_path):
    path = _write(tmp_path, BAD)
    with pytest.raises(StudyFileError) as info:
        load_study(path)
    err = info.value
    text = str(err)
    assert text.startswith(f"{path}: 10 problems in the study file:"), text
    found = {(p.table, p.key) for p in err.problems}
    assert found == {
        ("(top level)", "colour"),
        ("[sampling]", "samples"),
        ("[sampling]", "method"),
        ("[[parameters]] #1 (stiffness)", "connections"),
        ("[[parameters]] #2 (stiffness)", "quantity"),
        ("[[parameters]] #3 (mass)", "relative_spread"),
        ("[[parameters]] #4 (damping)", ""),
        ("[[parameters]] #5 (kp)", "relative_spread"),
        ("[[parameters]] #6 (gravity)", "absolute_spread"),
        ("[[outputs]] #1 (object_pose)", "thresholds"),
    }, err.problems  # (not [sensitivity]: its output's own problem is reported)
    # each message names the value that is wrong
    assert "'beam-middle'" in text and "beam-left, beam-right" in text
    assert "'sobol'" in text
    # a normal law 0.3 wide reaches 2 kg x (1 - 5 x 0.3) = -1 kg within 5 std
    assert "must stay positive" in text and "reaches -1 within" in text
    assert "already varied by [[parameters]] #1" in text
    assert "2: x, y), got 3 numbers" in text
    assert "'object_pose' is a time series; thresholds apply" in text
    # a spread, a number or a list, is reported once, by its key (before: once
    # for each kind, keys named by pydantic's internal names of the kinds)
    assert "input should be greater than or equal to 0 (got -0.1)" in text
    assert "function-after" not in text


def test_a_missing_scenario_is_named(tmp_path):
    path = _write(
        tmp_path,
        'scenario = "nowhere.toml"\n[sampling]\nsamples = 2\n'
        '[[parameters]]\nquantity = "gravity"\ndistribution = "uniform"\n'
        'absolute_spread = 0.1\n[[outputs]]\nquantity = "object_pose"\n',
    )
    with pytest.raises(StudyFileError, match="no scenario file 'nowhere.toml'"):
        load_study(path)


def test_an_immobile_scenario_has_no_connections_to_vary(tmp_path):
    path = _write(
        tmp_path,
        'scenario = "hanging_object"\n[sampling]\nsamples = 2\n'
        '[initial]\nfrom = "scenario"\n'
        '[[parameters]]\nquantity = "stiffness"\ndistribution = "lognormal"\n'
        "relative_spread = 0.1\n"
        '[[outputs]]\nquantity = "peak_elastic_force"\n',
    )
    with pytest.raises(StudyFileError) as info:
        load_study(path)
    keys = [(p.table, p.key) for p in info.value.problems]
    assert keys == [
        ("[[parameters]] #1 (stiffness)", "quantity"),
        ("[[outputs]] #1 (peak_elastic_force)", "quantity"),
    ]


@pytest.fixture(scope="module")
def shipped_study():
    with importlib.resources.as_file(SHIPPED) as path:
        return load_study(path, samples=3)


@pytest.mark.slow
def test_the_shipped_study_builds_the_laws_it_states(shipped_study):
    """Each law against the file's numbers and the scenario's nominal values."""
    study, scenario = shipped_study.study, shipped_study.scenario
    nominal = load_example("beam_lift")
    assert study.n_samples == 3 and study.sampling == "lhs"
    assert np.asarray(study.ts).shape == (61,)
    assert np.asarray(study.ts)[-1] == np.asarray(nominal.ts)[-1]
    assert (study.rtol, study.atol) == (1e-6, 1e-8)
    laws = {p.name: p for p in study.parameters}
    stiffness = laws["stiffness"]
    assert stiffness.relative and isinstance(stiffness.distribution, mc.LogNormal)
    expected = np.tile([0.2, 0.2, 0.2, 0.0, 0.0, 0.0], (2, 1))
    np.testing.assert_array_equal(stiffness.distribution.log_std, expected)
    damping = laws["damping"].distribution
    np.testing.assert_array_equal(damping.low, np.full((2, 6), 0.7))
    np.testing.assert_array_equal(damping.high, np.full((2, 6), 1.3))
    mass = laws["mass"]
    assert not mass.relative
    np.testing.assert_array_equal(mass.distribution.mean, [2.0, 0.3, 0.3])
    np.testing.assert_array_equal(mass.distribution.std, [0.1, 0.0, 0.0])
    assert laws["kp"].target == "forces"
    assert study.initial == "equilibrium"
    assert shipped_study.thresholds == {
        "peak_force": (82.0,),
        "force_rise": (0.9,),
        "deflection": (5e-3,),
        "pose": (),
    }
    assert study._labels()["connection"] == ["beam-left", "beam-right"]
    assert scenario.names == ("beam", "left", "right")


def test_the_examples_list_the_study_apart_from_the_scenarios(capsys):
    assert "beam_lift.study" not in example_files()
    assert main(["examples"]) == 0
    assert "beam_lift (study):" in capsys.readouterr().out


@pytest.mark.parametrize(
    "argv, message",
    [
        (["montecarlo", "summary"], "give the study's store"),
        (["montecarlo", "summary", "x", "--samples", "3"], "--samples applies to"),
        (["montecarlo", "study.toml"], "give the folder of the results with -o"),
        (
            ["montecarlo", "study.toml", "-o", "s", "--processes", "2"],
            "go together",
        ),
        (["montecarlo", "summary", "."], "is not a study store"),
        (["montecarlo", "nowhere.toml", "-o", "s"], "no such study file"),
    ],
)
def test_usage_errors_exit_2_without_traceback(
    tmp_path, monkeypatch, capsys, argv, message
):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err


# The shipped study's time span cut to its first 0.6 s (the lift's accelerating
# phase), with 13 output times: the studies run here (4 samples each) thus all
# compile the same programs.
SHORT_SPAN = "[time]\nstop = 0.6\nsamples = 13"


# The shipped study at small size: the short span, 4 samples; and its scenario
# named as a shipped example rather than a file beside it.
def _small_study(tmp_path):
    text = SHIPPED.read_text(encoding="utf-8")
    text = text.replace('scenario = "beam_lift.toml"', 'scenario = "beam_lift"')
    text = text.replace("[time]\nsamples = 61", SHORT_SPAN)
    assert 'scenario = "beam_lift"' in text and SHORT_SPAN in text
    return _write(tmp_path, text, "small.study.toml")


PROBABILITY = re.compile(
    r"P\((\w+)\[([\w-]+)\] > ([\d.e+-]+)\) = ([\d.]+)  \(95% CI ([\d.]+) to "
    r"([\d.]+), n = (\d+)\)"
)


@pytest.mark.slow
def test_montecarlo_runs_resumes_refuses_and_summarises(tmp_path, capsys):
    study = _small_study(tmp_path)
    store = tmp_path / "store"
    # the README's command, on a shorter span and with 4 samples
    paths = {"my_study/beam_lift.study.toml": str(study), "results/study": str(store)}
    run = readme_command("montecarlo", paths, samples=4)
    assert run == ["montecarlo", str(study), "-o", str(store), "--samples", "4"]
    assert main([*run, "-q"]) == 0, capsys.readouterr().err
    chunks = sorted(store.glob("chunk-*.npz"))
    stamps = [c.stat().st_mtime_ns for c in chunks]
    # re-run: every chunk is complete, nothing is computed again
    assert main(run) == 0, capsys.readouterr().err
    assert [c.stat().st_mtime_ns for c in chunks] == stamps
    assert "4 samples, 4 succeeded" in capsys.readouterr().out
    # another sample count is another study: refused, the store kept
    assert main(["montecarlo", str(study), "-o", str(store), "--samples", "5"]) == 2
    err = capsys.readouterr().err
    assert "holds another study" in err and "Traceback" not in err
    assert [c.stat().st_mtime_ns for c in chunks] == stamps

    assert main(["montecarlo", "summary", str(store)]) == 0
    out = capsys.readouterr().out
    ds = mc.open_study(store)
    # the draws: every sample's beam mass differs, the grasps' stay nominal
    assert np.all(ds["mass"].values[:, 1:] == 0.3)
    assert len(set(ds["mass"].values[:, 0])) == 4
    printed = PROBABILITY.findall(out)
    assert len(printed) == 3 * 2  # peak_force, force_rise, deflection: 1 each
    for output, connection, threshold, p, low, high, n in printed:
        values = ds[output].sel(connection=connection).values
        expected = np.mean(values > float(threshold))
        assert float(p) == pytest.approx(expected, abs=5e-5)
        assert int(n) == 4 and float(low) <= float(p) <= float(high)
    assert {c for _, c, *_ in printed} == {"beam-left", "beam-right"}
    assert "sensitivity (Spearman rank correlation" in out
    # with its chance level: over 4 samples 1.96 / sqrt(3) = 1.13, above any |rho|
    assert "peak_force[beam-left] (n = 4, chance below 1.13): " in out
    summary = json.loads((store / "summary" / "summary.json").read_text())
    peak = summary["outputs"]["peak_force"]["elements"]["beam-left"]
    assert peak["mean"] == pytest.approx(float(ds.peak_force[:, 0].mean()))
    written = {p.name for p in (store / "summary").iterdir()}
    assert written == {
        "summary.json",
        "histogram_peak_force.png",
        "histogram_force_rise.png",
        "histogram_deflection.png",
        "sensitivity_peak_force.png",
        "sensitivity_force_rise.png",
        "sensitivity_deflection.png",
        "quantiles_pose.png",
    }


@pytest.mark.slow
def test_the_shipped_study_studies_the_lift(tmp_path):
    """Before, every sample started from the nominal equilibrium with the nominal
    hold forces, then (with its grasps held at their commanded poses) from its
    own static equilibrium, where the frozen hold forces do not balance its
    reactions: either way a start-up transient raised the forces with no lift at
    all (force_rise about 1.5 N at lift_height = 0.0, and the same peak forces
    with and without the lift). Now each sample starts at rest in its own closed
    loop (object and grasps free under the controller): without a lift nothing
    moves, and the lift alone raises the grasp loads."""
    text = SHIPPED.read_text(encoding="utf-8")
    text = text.replace("[time]\nsamples = 61", SHORT_SPAN)
    scenario = (SHIPPED.parent / "beam_lift.toml").read_text(encoding="utf-8")
    assert "lift_height = 0.2 " in scenario and SHORT_SPAN in text
    results = {}
    for height in ("0.2", "0.0"):
        folder = tmp_path / height
        folder.mkdir()
        (folder / "beam_lift.toml").write_text(
            scenario.replace("lift_height = 0.2 ", f"lift_height = {height} ")
        )
        study = _write(folder, text, "beam_lift.study.toml")
        store = folder / "store"
        assert (
            main(["montecarlo", str(study), "-o", str(store), "--samples", "4", "-q"])
            == 0
        )
        results[height] = mc.open_study(store)
    lift, still = results["0.2"], results["0.0"]
    # the same draws, each sample at rest in its own closed loop
    np.testing.assert_array_equal(lift["mass"].values, still["mass"].values)
    start = lift["pose"].isel(time=0).sel(coordinate="z").values
    np.testing.assert_array_equal(
        start, still["pose"].isel(time=0).sel(coordinate="z").values
    )
    assert np.ptp(start) > 1e-3
    # without a lift the loads stay at their start (to the study's tolerances,
    # rtol 1e-6: a start-up transient raised them by about 1.5 N) ...
    rise, rest = lift["force_rise"].values, still["force_rise"].values
    assert np.all(rest < 1e-3), rest
    # ... and the lift's accelerating phase (min-jerk: up to 0.42 s of 2 s)
    # raises every sample's loads
    assert np.all(rise > 0.3), rise
    assert np.all(lift["peak_force"].values > still["peak_force"].values + 0.3)
    # without a lift, the object stays at its start; with it, it rises
    z_end = lift["pose"].isel(time=-1).sel(coordinate="z").values
    assert np.all(z_end - start > 0.02)
    z_still = still["pose"].isel(time=-1).sel(coordinate="z").values
    assert np.all(np.abs(z_still - start) < 1e-5)


def test_rank_correlations_rank_what_the_output_follows():
    """y = a^3 - 0.01 b0 has the ranks of a (rho = 1); b0's rho from the ranks by
    hand (Spearman's 1 - 6 sum d^2 / n(n^2 - 1)); b1, held fixed, is left out."""
    import xarray as xr

    a = np.array([0.3, -1.0, 2.0, 0.5, 1.1])
    b0 = np.array([5.0, 1.0, 4.0, 3.0, 2.0])
    ds = xr.Dataset(
        {
            "status": ("sample", np.zeros(5, np.int32)),
            "a": ("sample", a),
            "b": (("sample", "b_axis"), np.stack([b0, np.full(5, 7.0)], axis=1)),
            "y": ("sample", a**3 - 0.01 * b0),
        },
        attrs={"study": json.dumps({"parameters": [{"name": "a"}, {"name": "b"}]})},
    )
    rho = mc.rank_correlations(ds, "y")
    assert list(rho["parameter"].values) == ["a", "b[0]"]
    # ranks of y = ranks of a: 2 1 5 3 4; of b0: 5 1 4 3 2 -> d^2 = 9+0+1+0+4 = 14
    assert rho.sel(parameter="a") == pytest.approx(1.0)
    assert rho.sel(parameter="b[0]") == pytest.approx(1 - 6 * 14 / (5 * 24))
    assert rho.attrs["n"] == 5


@pytest.mark.slow
def test_time_and_solver_overrides_are_checked_and_followed(tmp_path):
    """A `[time]` span beyond the scenario's force samples and a step budget above
    the limit are problems of the file (they raised inside the study), and a study
    that starts later starts its pose-tracking lift later too."""
    tail = (
        '[[parameters]]\nquantity = "mass"\ndistribution = "lognormal"\n'
        'relative_spread = 0.1\n[[outputs]]\nquantity = "final_pose_error"\n'
    )
    sampled = 'scenario = "hanging_object"\n[sampling]\nsamples = 2\n'
    # the scenario starts turning: its samples cannot start at rest
    with pytest.raises(StudyFileError, match="the scenario starts with velocities"):
        load_study(_write(tmp_path, sampled + tail))
    sampled += '[initial]\nfrom = "scenario"\n'
    path = _write(tmp_path, sampled + "[time]\nstop = 5.0\n" + tail)
    with pytest.raises(StudyFileError) as info:
        load_study(path)
    assert {(p.table, p.key) for p in info.value.problems} == {("[time]", "stop")}
    assert "outside the scenario's force samples" in str(info.value)
    lift = 'scenario = "beam_lift"\n[sampling]\nsamples = 2\n'
    path = _write(tmp_path, lift + "[solver]\nmax_steps = 1099511627776\n" + tail)
    with pytest.raises(StudyFileError, match="less than or equal to 2147483647"):
        load_study(path)
    path = _write(tmp_path, lift + "[time]\nstart = 0.5\n" + tail)
    study = load_study(path).study
    assert float(study.ts[0]) == 0.5
    assert float(study.inputs.forces.start) == 0.5
