"""Bounded inputs: oversized, deeply nested, astronomically large or damaged inputs
are refused with a message naming the file, table and key (never a traceback or
an out-of-memory crash), and dense force samples cost what their shape needs."""

import math
import warnings

import numpy as np
import pytest
from test_scenario_file import IMMOBILE, TINY, coupling, write

import elasticoop as eo
from elasticoop import _forces
from elasticoop._cli import main
from elasticoop._config import ScenarioError, load_scenario

CONSTANT = "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]"
BIG = 10**400  # beyond float64 and int64


def _rejected(tmp_path, capsys, text, where, *words, name="bad.toml"):
    """`elasticoop check` refuses `text` with `where` (table and key) and `words`
    in its message, exit code 2, no traceback."""
    path = write(tmp_path, text, name)
    code = main(["check", str(path)])
    err = capsys.readouterr().err
    assert code == 2, err
    assert str(path) in err and where in err, err
    for word in words:
        assert word in err, err
    assert "Traceback" not in err and "internal error" not in err
    return err


def _samples_scenario(tmp_path, ts, fz, name="f.csv"):
    """TINY with `grip.fz` sampled at `ts` from a CSV file (no initial momentum)."""
    np.savetxt(
        tmp_path / name,
        np.column_stack([ts, fz]),
        delimiter=",",
        header="t,grip.fz",
        comments="",
        fmt="%.17g",
    )
    text = TINY.replace(CONSTANT, f'[forces]\nsamples = "{name}"')
    return write(tmp_path, text.replace("velocity = [0.0, 0.0, 0.5]\n", ""))


# -- dense force samples ----------------------------------------------------------

# 20001 samples on [0, 0.2] s: a smooth 5 Hz wave on 15 N.
DENSE_TS = np.linspace(0.0, 0.2, 20001)
OMEGA = 2 * math.pi * 5.0
DENSE_FZ = 15.0 + 5.0 * np.sin(OMEGA * DENSE_TS)


def test_dense_smooth_samples_hand_only_their_kinks_to_the_solver():
    # One component a densely sampled smooth wave (no kink worth a jump time), one
    # a ramp-hold-ramp with corners at t = 0.3 and 0.6 s exactly on samples, and
    # collinear samples along each ramp (no kinks either).
    ts = np.linspace(0.0, 1.0, 20001)
    F = np.zeros((ts.size, 2, 6))
    F[:, 0, 2] = 15.0 + 5.0 * np.sin(2 * math.pi * ts)
    F[:, 1, 0] = np.interp(ts, [0.0, 0.3, 0.6, 1.0], [0.0, 3.0, 3.0, -1.0])
    force = eo.SampledForce(ts, F)
    np.testing.assert_array_equal(force.jump_ts, [0.0, 0.3, 0.6, 1.0])
    # the interpolant itself is unchanged: every sample is still used
    assert force.ts.shape == (20001,)
    np.testing.assert_allclose(force(0.45, None, None)[1, 0], 3.0, rtol=1e-14)


def test_jump_times_can_be_given():
    ts = np.linspace(0.0, 1.0, 5)
    force = eo.SampledForce(ts, np.zeros((5, 1, 6)), jump_ts=[0.5, 0.25])
    np.testing.assert_array_equal(force.jump_ts, [0.25, 0.5])


def test_too_many_kinks_keep_the_largest_with_a_warning(monkeypatch):
    # A zigzag (every sample a kink) with one spike: with room for 3 kinks besides
    # the two ends, the three around the spike are the largest slope changes.
    monkeypatch.setattr(_forces, "MAX_JUMP_TIMES", 5)
    ts = np.linspace(0.0, 1.0, 101)
    values = np.where(np.arange(101) % 2 == 0, 0.0, 1.0)
    values[50] = 10.0
    F = np.zeros((101, 1, 6))
    F[:, 0, 2] = values
    with pytest.warns(UserWarning, match="only the 3 largest"):
        force = eo.SampledForce(ts, F)
    np.testing.assert_array_equal(force.jump_ts, ts[[0, 49, 50, 51, 100]])


@pytest.mark.slow
def test_dense_force_csv_runs_in_few_steps_and_matches_newton(tmp_path):
    # Every sample used to be a jump time: 20000 steps at least, and a cost per step
    # that grows with the number of samples. Internal forces cancel, so the centre
    # of mass follows M z_c'' = F_z(t) - M g exactly.
    s = load_scenario(_samples_scenario(tmp_path, DENSE_TS, DENSE_FZ))
    traj = s.simulate()
    assert int(traj.status) == 0
    assert int(traj.n_steps) < 1000
    masses = np.array([1.0, 0.2])
    total = masses.sum()
    t = np.asarray(traj.ts)
    z_c = np.asarray(traj.y[:, :, 2]) @ masses / total
    force_part = 15.0 * t**2 / 2 + 5.0 * (t / OMEGA - np.sin(OMEGA * t) / OMEGA**2)
    expected = z_c[0] - 9.81 * t**2 / 2 + force_part / total
    np.testing.assert_allclose(z_c, expected, rtol=0, atol=1e-8)


def test_check_reports_what_a_samples_file_costs(tmp_path, capsys):
    path = _samples_scenario(tmp_path, DENSE_TS, DENSE_FZ)
    assert main(["check", str(path)]) == 0
    out = capsys.readouterr().out
    assert "SampledForce, 20001 samples from 0 to 0.2 s" in out, out
    assert "2 of them handed to the solver as jump times" in out, out
    # 11 output samples of 49 numbers (2 bodies, 1 connection), 8 bytes each
    assert f"results: about {11 * 49 * 8 / 1024:.3g} KiB (limit 1 GiB)" in out, out
    # on disk: 61 numbers per sample (the applied forces too), 8 bytes each in
    # trajectory.nc and at most 25 in trajectory.csv, 64 KiB for the netCDF layout
    # and for summary.json, 2 MiB for the plots
    files = 11 * 61 * (8 + 25) + 2 * 64 * 1024 + 2 * 2**20
    assert f"the files of a run take up to {files / 2**20:.3g} MiB on disk" in out


# -- sizes, step budgets and large integers ---------------------------------------


@pytest.mark.parametrize("samples", [100_000_000, 300_000_000, 10**30])
def test_output_samples_beyond_the_memory_limit_are_refused(tmp_path, capsys, samples):
    text = TINY.replace("samples = 11", f"samples = {samples}")
    err = _rejected(
        tmp_path,
        capsys,
        text,
        "table [time], key 'samples'",
        "over the limit of 1 GiB",
        "use at most 2739137 samples",  # 2^30 bytes / (49 numbers x 8 bytes)
    )
    if samples == 100_000_000:
        # 49 numbers of 8 bytes per sample
        assert f"need {100_000_000 * 49 * 8 / 2**30:.3g} GiB" in err, err


def test_output_samples_at_the_limit_are_accepted(tmp_path):
    # the largest count that fits is fine (the check is not a blanket refusal)
    text = TINY.replace("samples = 11", "samples = 2739137")
    assert load_scenario(write(tmp_path, text)).ts.shape == (2739137,)


def test_step_budget_must_be_an_integer_in_range(tmp_path, capsys):
    for value, words in (
        ("2.5", "valid integer (got 2.5)"),
        (str(10**30), "less than or equal to 2147483647"),
    ):
        text = TINY.replace("[time]", f"[solver]\nmax_steps = {value}\n[time]")
        _rejected(tmp_path, capsys, text, "table [solver], key 'max_steps'", words)
    for value in (10**30, 0):
        with pytest.raises(
            ValueError, match=r"SimulationOptions\.max_steps must be a positive"
        ):
            eo.SimulationOptions(max_steps=value)
    assert eo.SimulationOptions(max_steps=2**31 - 1).max_steps == 2**31 - 1


def test_astronomically_large_numbers_are_named_briefly(tmp_path, capsys):
    err = _rejected(
        tmp_path,
        capsys,
        TINY.replace("mass = 1.0", f"mass = {BIG}"),
        "table [[bodies]] #1 (obj), key 'mass'",
        "number too large: an integer of 401 digits lies beyond the float64 range",
    )
    assert "0" * 30 not in err
    err = _rejected(
        tmp_path,
        capsys,
        TINY.replace('name = "tiny"', f"name = {BIG}"),
        "table (top level), key 'name'",
        "input should be a valid string (got an integer of 401 digits)",
    )
    # (a float field: the options' check, below the annotations' run-time check)
    from elasticoop._options import _positive

    with pytest.raises(ValueError, match="S.rtol must be a positive number, got a neg"):
        _positive(-BIG, "rtol", "S")


@pytest.mark.parametrize("depth", [2000, 100_000])
def test_deeply_nested_toml_is_a_scenario_problem(tmp_path, capsys, depth):
    text = "x = " + "[" * depth + "]" * depth + "\n" + TINY
    path = write(tmp_path, text, "deep.toml")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "deep.toml" in err and "nested too deeply" in err, err
    assert "Traceback" not in err


def test_oversized_scenario_file_is_refused(tmp_path, capsys):
    text = TINY + "#" * (16 * 2**20) + "\n"
    path = write(tmp_path, text, "huge.toml")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "huge.toml" in err and "over the limit of 16 MiB" in err, err


def test_oversized_data_file_is_refused(tmp_path, capsys, monkeypatch):
    from elasticoop._config import data_files

    monkeypatch.setattr(data_files, "MAX_DATA_FILE_BYTES", 100)
    path = _samples_scenario(tmp_path, np.linspace(0.0, 1.0, 30), np.ones(30))
    _rejected(
        tmp_path,
        capsys,
        path.read_text(),
        "table [forces], key 'samples'",
        "file 'f.csv' holds",
        "over the limit of 100 bytes for a data file",
    )


def test_samples_beyond_the_memory_limit_are_refused(tmp_path, capsys, monkeypatch):
    from elasticoop._config import build

    monkeypatch.setattr(build, "MAX_SAMPLES_BYTES", 1000)
    path = _samples_scenario(tmp_path, np.linspace(0.0, 1.0, 20), np.ones(20))
    # 20 rows x 2 bodies x 6 components x 8 bytes = 1920 bytes
    _rejected(
        tmp_path,
        capsys,
        path.read_text(),
        "table [forces], key 'samples'",
        "file 'f.csv' has 20 rows",
        "1.88 KiB, over the limit of 1000 bytes; resample the file",
    )


# -- data files: each problem said as it is ---------------------------------------


def _forces_from(name):
    return TINY.replace(CONSTANT, f'[forces]\nsamples = "{name}"')


def _immobile_k(name):
    return IMMOBILE.replace('K = "K.csv"', f'K = "{name}"')


def _data_files(tmp_path):
    good = coupling([1e3] * 3 + [5.0] * 3)
    np.save(tmp_path / "D.npy", coupling([2.0] * 3 + [0.01] * 3))
    (tmp_path / "folder").mkdir()
    (tmp_path / "folder.npy").mkdir()
    (tmp_path / "header.csv").write_text("t,grip.fz\n")
    (tmp_path / "one_row.csv").write_text("t,grip.fz\n0,1\n")
    (tmp_path / "random.npy").write_bytes(np.random.default_rng(0).bytes(1000))
    (tmp_path / "random.csv").write_bytes(bytes(range(128, 256)) * 8)
    (tmp_path / "empty.npy").write_bytes(b"")
    (tmp_path / "empty.csv").write_text("# nothing\n")
    np.save(tmp_path / "complex.npy", good.astype(complex) * (1 + 1j))
    np.save(tmp_path / "objects.npy", np.array([None, 1], dtype=object), True)
    np.save(tmp_path / "text.npy", np.array([["a", "b"], ["c", "d"]]))
    np.save(tmp_path / "truncated.npy", good)
    data = (tmp_path / "truncated.npy").read_bytes()
    (tmp_path / "truncated.npy").write_bytes(data[:-100])
    asym = good.copy()
    asym[0, 1] = 3.0
    np.savetxt(tmp_path / "K_asym.csv", asym, delimiter=",")
    np.savetxt(tmp_path / "K_neg.csv", -good, delimiter=",")


# (name, scenario text, table and key, words in the message)
DATA_FILES = [
    (
        "folder as a CSV",
        _forces_from("folder"),
        "table [forces], key 'samples'",
        "'folder' is a folder, not a data file",
    ),
    (
        "folder as a .npy",
        _immobile_k("folder.npy"),
        "table [immobile], key 'K'",
        "'folder.npy' is a folder, not a data file",
    ),
    (
        "header-only CSV",
        _forces_from("header.csv"),
        "table [forces], key 'samples'",
        "file 'header.csv' has no rows of samples, only a header",
    ),
    (
        "CSV of one row",
        _forces_from("one_row.csv"),
        "table [forces], key 'samples'",
        "file 'one_row.csv' has 1 row: it needs at least 2 rows of samples",
    ),
    (
        "random bytes as .npy",
        _immobile_k("random.npy"),
        "table [immobile], key 'K'",
        "file 'random.npy' is not a .npy file",
    ),
    (
        "random bytes as CSV",
        _forces_from("random.csv"),
        "table [forces], key 'samples'",
        "file 'random.csv' is not a text file",
    ),
    (
        "empty .npy",
        _immobile_k("empty.npy"),
        "table [immobile], key 'K'",
        "file 'empty.npy' is empty",
    ),
    (
        "CSV matrix of comments only",
        _immobile_k("empty.csv"),
        "table [immobile], key 'K'",
        "file 'empty.csv' holds no numbers",
    ),
    (
        "complex .npy",
        _immobile_k("complex.npy"),
        "table [immobile], key 'K'",
        "file 'complex.npy' holds complex numbers, not real numbers",
    ),
    (
        "object .npy",
        _immobile_k("objects.npy"),
        "table [immobile], key 'K'",
        "file 'objects.npy' holds Python objects",
    ),
    (
        "text .npy",
        _immobile_k("text.npy"),
        "table [immobile], key 'K'",
        "file 'text.npy' holds entries of dtype <U1, not real numbers",
    ),
    (
        "truncated .npy",
        _immobile_k("truncated.npy"),
        "table [immobile], key 'K'",
        "file 'truncated.npy' is damaged or truncated",
    ),
    (
        "non-symmetric K",
        _immobile_k("K_asym.csv"),
        "table [immobile], key 'K'",
        "K must be symmetric, but its largest entry of |K - K^T| is 3 (at most "
        "1e-10 max|K| = 1e-07 allowed)",
    ),
    (
        "indefinite K",
        _immobile_k("K_neg.csv"),
        "table [immobile], key 'K'",
        "K must be positive semidefinite, but its smallest eigenvalue is -2000 (at "
        "least -1e-09 max|K| = -1e-06 allowed)",
    ),
]


@pytest.mark.parametrize(
    "name, text, where, words", DATA_FILES, ids=[d[0] for d in DATA_FILES]
)
def test_data_file_problems_say_what_is_wrong(
    tmp_path, capsys, name, text, where, words
):
    _data_files(tmp_path)
    err = _rejected(tmp_path, capsys, text, where, words)
    assert ", got" not in err and "pickled" not in err, err
    assert "not found" not in err, err


def test_folder_given_as_the_scenario_file(tmp_path, capsys):
    assert main(["check", str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert "a folder, not a scenario file" in err, err


def test_loading_is_quiet_about_what_it_reports(tmp_path):
    # no warning escapes for a problem that is reported as one
    (tmp_path / "K.csv").write_text("# nothing\n")
    np.save(tmp_path / "D.npy", np.zeros((12, 12)))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        with pytest.raises(ScenarioError, match="holds no numbers"):
            load_scenario(write(tmp_path, IMMOBILE))


# -- huge numbers and byte-order marks (the second audit) -------------------------

WEIGHT = """\
[forces.pose_tracking]
lift_height = 0.1
lift_time = 0.1
kp = [1e3, 1e3, 1e3, 1.0, 1.0, 1.0]
kd = [10.0, 10.0, 10.0, 0.1, 0.1, 0.1]
feedforward = "weight"
"""


@pytest.mark.parametrize(
    "feedforward, start",
    [("weight", ""), ("hold", ""), ("hold", '[initial]\nfrom = "equilibrium"\n')],
)
def test_a_mass_of_1e308_is_named(tmp_path, capsys, feedforward, start):
    # Was: "weight": a traceback ("PoseTracking.feedforward must be finite") and
    # exit 1; "hold" from the given poses: accepted, then NaN at t = 0 (exit 3);
    # "hold" from the equilibrium: "the stiffness restricted to the 6 free ones
    # is singular", which names neither the mass nor its value.
    text = TINY.replace(CONSTANT, WEIGHT.replace('"weight"', f'"{feedforward}"'))
    text = text.replace("velocity = [0.0, 0.0, 0.5]\n", "")
    text = text.replace("angle_rates = { degrees = [0.0, 0.0, 30.0] }\n", "")
    text = text.replace("[initial.obj]", start + "[initial.obj]")
    _rejected(
        tmp_path,
        capsys,
        text.replace("mass = 1.0", "mass = 1e308"),
        "table [[bodies]] #1 (obj), key 'mass'",
        "1e+308 lies beyond ±1e+15, the largest magnitude accepted",
    )
    # the largest accepted value is accepted
    path = write(tmp_path, text.replace("mass = 1.0", "mass = 1e15"), "ok.toml")
    assert main(["check", str(path), "-q"]) == 0, capsys.readouterr().err


@pytest.mark.parametrize(
    "table, old, new, where",
    [
        ("TINY", "stop = 0.2", "stop = 1e300", "table [time], key 'stop'"),
        ("TINY", "1e3, 1e3, 1e3, 5.0", "1e3, 1e300, 1e3, 5.0", "key 'stiffness[1]'"),
        (
            "TINY",
            "position = [0.0, 0.0, 1.0]",
            "position = [0.0, -1e20, 1.0]",
            "key 'position[1]'",
        ),
        ("TINY", "gravity = 9.81", "gravity = 1e300", "table [model], key 'gravity'"),
        (
            "TINY",
            "15.0, 0.0, 0.0, 0.0]",
            "1e300, 0.0, 0.0, 0.0]",
            "table [forces.constant]",
        ),
    ],
)
def test_huge_numbers_anywhere_in_a_scenario_are_named(
    tmp_path, capsys, table, old, new, where
):
    # Was: accepted, then a run that stops with NaN at t = 0 or overflows (exit 3)
    text = globals()[table]
    assert old in text
    _rejected(tmp_path, capsys, text.replace(old, new), where, "lies beyond ±1e+15")


def test_huge_entries_of_data_files_are_named(tmp_path, capsys):
    # Was: a force sample or a stiffness entry of 1e300 was accepted and the run
    # stopped with NaN (exit 3).
    ts = np.linspace(0.0, 0.2, 5)
    path = _samples_scenario(tmp_path, ts, np.where(ts > 0.1, 1e300, 15.0))
    _rejected(
        tmp_path,
        capsys,
        path.read_text(),
        "table [forces], key 'samples'",
        "file 'f.csv', column 'grip.fz', data row 4: 1e+300 lies beyond ±1e+15",
    )
    K = coupling([1e3] * 6)
    K[0, 0] = K[6, 6] = 1e300
    np.savetxt(tmp_path / "K.csv", K, delimiter=",")
    np.save(tmp_path / "D.npy", 0.01 * coupling([1e3] * 6))
    _rejected(
        tmp_path,
        capsys,
        IMMOBILE,
        "table [immobile], key 'K'",
        "file 'K.csv', entry [0][0]: 1e+300 lies beyond ±1e+15",
    )


def test_byte_order_marks_in_scenario_and_data_files_are_read(tmp_path, capsys):
    # Was: a TOML file starting with a byte-order mark was "not valid TOML:
    # Invalid statement (at line 1, column 1)"; a matrix CSV with one "could not be
    # read as numbers: could not convert string '\ufeff...'".
    bom = b"\xef\xbb\xbf"
    np.savetxt(tmp_path / "K.csv", coupling([1e3] * 6), delimiter=",")
    (tmp_path / "K.csv").write_bytes(bom + (tmp_path / "K.csv").read_bytes())
    np.save(tmp_path / "D.npy", 0.01 * coupling([1e3] * 6))
    path = write(tmp_path, IMMOBILE)
    path.write_bytes(bom + path.read_bytes())
    assert main(["check", str(path)]) == 0, capsys.readouterr().err


def test_control_characters_in_the_name_are_named(tmp_path, capsys):
    # Was: accepted; `run` simulated, then failed writing trajectory.nc with exit 1,
    # "internal error (ValueError: VLEN strings do not support embedded NULLs)".
    _rejected(
        tmp_path,
        capsys,
        TINY.replace('name = "tiny"', 'name = "tiny\\u0000"'),
        "table (top level), key 'name'",
        "holds control characters (U+0000)",
    )
    text = TINY.replace('name = "tiny"', 'name = "tiny"\ndescription = "a\\tb\\nc"')
    assert main(["check", str(write(tmp_path, text, "ok.toml")), "-q"]) == 0
