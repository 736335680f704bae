"""Measured-data files (CSV, netCDF) read into `Experiment`s: values and units
against the arrays they were written from, and malformed files rejected with
every problem named by file, column and line. Nothing here simulates."""

import math

import jax.numpy as jnp
import numpy as np
import pytest

import elasticoop as eo
from elasticoop import DataFileError, SampledForce, load_experiment
from elasticoop._config import load_scenario
from elasticoop._identify.differentiate import savitzky_golay

# An object and one grasp (ZXZ angles), a constant force on the grasp.
TWO_BODIES = """\
name = "pair"
[model]
kind = "mobile"
[[bodies]]
name = "obj"
mass = 1.0
inertia = [0.01, 0.01, 0.01]
[[bodies]]
name = "grip"
mass = 0.2
inertia = [1e-3, 1e-3, 1e-3]
[[connections]]
bodies = ["obj", "grip"]
stiffness = [1e3, 1e3, 1e3, 5.0, 5.0, 5.0]
damping = [5.0, 5.0, 5.0, 0.05, 0.05, 0.05]
[initial.obj]
position = [0.0, 0.0, 1.0]
angles = { degrees = [0.0, 90.0, 0.0] }
[initial.grip]
position = [0.2, 0.0, 1.0]
angles = { degrees = [0.0, 90.0, 0.0] }
[forces.constant]
grip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]
[time]
stop = 0.3
samples = 4
"""
COORDS = ("x", "y", "z", "psi", "theta", "phi")
BODIES = ("obj", "grip")


@pytest.fixture(scope="module")
def scenario(tmp_path_factory):
    path = tmp_path_factory.mktemp("scenario") / "pair.toml"
    path.write_text(TWO_BODIES)
    return load_scenario(path)


def known_motion(n=4):
    """Distinct values for every sample, body and coordinate (angles in rad)."""
    t = np.linspace(0.0, 0.3, n)
    y = np.empty((n, 2, 6))
    for b in range(2):
        for c in range(6):
            y[:, b, c] = 0.1 * (b + 1) + 0.01 * c + t * (c + 1)
    return t, y


def write_csv(path, t, y, ydot=None, sigma=None, blank=(), comment=True):
    """A CSV with positions in m and angles in degrees (`[deg]` headers)."""
    header = ["t"] + [
        f"{b}.{c}" + (" [deg]" if k >= 3 else "")
        for b in BODIES
        for k, c in enumerate(COORDS)
    ]
    scale = np.array([1, 1, 1] + [180 / math.pi] * 3)
    table = (y * scale).reshape(len(t), -1)
    if ydot is not None:
        header += [
            f"ydot.{b}.{c}" + (" [deg/s]" if k >= 3 else " [m/s]")
            for b in BODIES
            for k, c in enumerate(COORDS)
        ]
        table = np.hstack([table, (ydot * scale).reshape(len(t), -1)])
    lines = ["# a comment line"] if comment else []
    lines.append(",".join(header))
    if sigma is not None:
        lines.append(",".join(["sigma"] + [repr(s) for s in sigma]))
    for r, row in enumerate(table):
        cells = [repr(float(t[r]))] + [repr(float(v)) for v in row]
        for rr, cc in blank:
            if rr == r:
                cells[cc + 1] = ""
        lines.append(",".join(cells))
    path.write_text("\n".join(lines) + "\n")
    return path


def test_csv_values_units_missing_samples_and_noise(scenario, tmp_path):
    t, y = known_motion()
    ydot = 2.0 * y
    sigma = [1e-3] * 3 + [0.5] * 3 + [2e-3] * 3 + [1.0] * 3  # m and deg
    sigma += [1e-2] * 3 + [5.0] * 3 + [2e-2] * 3 + [10.0] * 3  # m/s and deg/s
    path = write_csv(
        tmp_path / "m.csv", t, y, ydot, sigma=sigma, blank=[(1, 2), (2, 10)]
    )
    e = load_experiment(path, scenario)
    expected = y.copy()
    expected[1, 0, 2] = np.nan  # column 2: obj.z
    expected[2, 1, 4] = np.nan  # column 10: grip.theta
    np.testing.assert_allclose(np.asarray(e.ts), t)
    np.testing.assert_allclose(np.asarray(e.y), expected, rtol=1e-12)
    np.testing.assert_allclose(np.asarray(e.ydot), ydot, rtol=1e-12)
    deg = math.pi / 180
    np.testing.assert_allclose(
        np.asarray(e.sigma),
        [[1e-3] * 3 + [0.5 * deg] * 3, [2e-3] * 3 + [deg] * 3],
    )
    np.testing.assert_allclose(
        np.asarray(e.sigma_ydot),
        [[1e-2] * 3 + [5 * deg] * 3, [2e-2] * 3 + [10 * deg] * 3],
    )
    # the initial state and the forces are the scenario's
    np.testing.assert_allclose(np.asarray(e.y_init), np.asarray(scenario.y_init))
    assert e.forces is scenario.forces or np.allclose(
        np.asarray(e.forces(0.0, e.y_init, e.ydot_init)),
        np.asarray(scenario.forces(0.0, e.y_init, e.ydot_init)),
    )
    assert load_experiment(path, scenario, velocities=False).ydot is None


def test_csv_force_columns_and_the_scenario_time_grid(scenario, tmp_path):
    t, y = known_motion()
    path = write_csv(tmp_path / "f.csv", t, y)
    lines = path.read_text().splitlines()
    lines[1] += ",grip.fz [N],obj.q2"
    for k in range(2, len(lines)):
        lines[k] += f",{10.0 + k},{0.5 * k}"
    path.write_text("\n".join(lines) + "\n")
    e = load_experiment(path, scenario)
    assert isinstance(e.forces, SampledForce)
    F = np.asarray(e.forces(float(t[1]), e.y_init, e.ydot_init))
    expected = np.zeros((2, 6))
    expected[1, 2], expected[0, 4] = 13.0, 1.5  # data row 2 is line 4 of the file
    np.testing.assert_allclose(F, expected)

    # without a time column, the rows are the scenario's [time] samples
    no_time = tmp_path / "grid.csv"
    rows = [
        line.split(",", 1)[1]
        for line in write_csv(no_time, t, y).read_text().splitlines()[1:]
    ]
    no_time.write_text("\n".join(rows) + "\n")
    e = load_experiment(no_time, scenario)
    np.testing.assert_allclose(np.asarray(e.ts), np.asarray(scenario.ts))
    no_time.write_text("\n".join(rows[:-1]) + "\n")
    with pytest.raises(DataFileError, match="grid of 4 times, but the file has 3"):
        load_experiment(no_time, scenario)


def test_a_bad_csv_lists_every_problem_with_column_and_line(scenario, tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text(
        "# measured\n"
        "t,obj.x,obj.y,obj.z,obj.psi,obj.theta [deg],obj.phi [grad],ghost.x,"
        "grip.q\n"
        "0.0,1,2,3,4,5,6,7,8\n"
        "0.1,oops,2,3,4,5,6,7,8\n"
        "0.1,1,2,3,4,5,6,7,8\n"
        "0.3,1,2\n"
    )
    with pytest.raises(DataFileError) as info:
        load_experiment(path, scenario)
    text = str(info.value)
    assert text.startswith(f"{path}: ")
    for expected in (
        "column 'obj.psi', line 2 (header): an angle column needs its unit",
        "column 'obj.phi', line 2 (header): unit 'grad' not accepted",
        "column 'ghost.x', line 2 (header): no body named 'ghost' (bodies: obj, grip)",
        "column 'grip.q', line 2 (header): 'q' is not a coordinate",
        "column 'obj.x', line 4: not a number: 'oops'",
        "column 't', line 5: times must increase: t = 0.1 s follows t = 0.1 s",
        "line 6: has 3 cells but the header (line 2) has 9",
    ):
        assert expected in text, expected
    assert "Traceback" not in text


def test_the_result_columns_of_a_run_are_named_once(scenario, tmp_path):
    """A run's trajectory.csv given as data: its energy and force columns, which
    are not measured, make one problem that says what to keep, not one each."""
    t, y = known_motion()
    path = write_csv(tmp_path / "run.csv", t, y, comment=False)
    lines = path.read_text().splitlines()
    extra = ["work [J]", "kinetic_energy [J]", "elastic_force.obj.x [N]"]
    lines[0] += "," + ",".join(extra)
    lines[1:] = [line + ",0.0,0.0,0.0" for line in lines[1:]]
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFileError) as info:
        load_experiment(path, scenario)
    text = str(info.value)
    assert (
        "3 columns of a run's results (work, kinetic_energy, elastic_force.obj.x)"
        in (text)
    )
    assert text.count("not measured data") == 1 and "trajectory.nc" in text
    assert "not a column name" not in text


def test_missing_columns_all_or_none_velocities_and_bad_noise(scenario, tmp_path):
    t, y = known_motion()
    path = write_csv(tmp_path / "m.csv", t, y)
    lines = path.read_text().splitlines()
    header = lines[1].split(",")
    keep = [
        k for k, name in enumerate(header) if name not in ("grip.y", "obj.phi [deg]")
    ]
    noise = ["sigma"] + ["-1"] + ["0.1"] * (len(header) - 2)
    body = [
        ",".join(c for k, c in enumerate(row.split(",")) if k in keep)
        for row in [lines[1], ",".join(noise)] + lines[2:]
    ]
    body[0] += ",ydot.obj.x [m/s]"
    for k in range(1, len(body)):
        body[k] += ",0.1" if k == 1 else ",0.0"
    path.write_text("\n".join(body) + "\n")
    with pytest.raises(DataFileError) as info:
        load_experiment(path, scenario)
    text = str(info.value)
    assert "missing columns obj.phi, grip.y: every coordinate" in text
    assert "missing columns ydot.obj.y, ydot.obj.z" in text
    assert "column 'obj.x', line 2 (sigma): the noise level must be a positive" in text


def test_files_that_are_not_data(scenario, tmp_path):
    with pytest.raises(DataFileError, match="not found"):
        load_experiment(tmp_path / "absent.csv", scenario)
    other = tmp_path / "data.xlsx"
    other.write_text("x")
    with pytest.raises(DataFileError, match="unknown kind of data file '.xlsx'"):
        load_experiment(other, scenario)
    broken = tmp_path / "broken.nc"
    broken.write_text("not netCDF")
    with pytest.raises(DataFileError, match="not a readable netCDF file"):
        load_experiment(broken, scenario)


def netcdf(path, t, y, bodies=BODIES, units=("m",) * 3 + ("rad",) * 3):
    """A Dataset in the layout of `trajectory.nc`, written to `path`."""
    import xarray as xr

    ds = xr.Dataset(
        {
            "y": (("time", "body", "coordinate"), y),
            "ydot": (("time", "body", "coordinate"), 3.0 * y),
            "kinetic_energy": ("time", np.zeros(len(t))),
        },
        coords={
            "time": t,
            "body": list(bodies),
            "coordinate": list(COORDS),
            "coordinate_unit": ("coordinate", list(units)),
        },
        attrs={"convention": "zxz"},
    )
    ds.to_netcdf(path, engine="h5netcdf")
    return path


def test_netcdf_in_the_layout_of_trajectory_nc(scenario, tmp_path):
    t, y = known_motion()
    y[2, 0, 1] = np.nan
    # bodies in another order than the scenario's: matched by name
    path = netcdf(tmp_path / "run.nc", t, y[:, ::-1], bodies=BODIES[::-1])
    e = load_experiment(path, scenario)
    np.testing.assert_allclose(np.asarray(e.y), y)
    np.testing.assert_allclose(np.asarray(e.ydot), 3.0 * y)
    assert e.sigma is None
    assert load_experiment(path, scenario, velocities=False).ydot is None
    degrees = netcdf(
        tmp_path / "deg.nc", t, np.degrees(y), units=("m",) * 3 + ("deg",) * 3
    )
    np.testing.assert_allclose(
        np.asarray(load_experiment(degrees, scenario).y)[..., 3:], y[..., 3:]
    )

    bad_t = t.copy()
    bad_t[2] = bad_t[1]
    bad = netcdf(tmp_path / "bad.nc", bad_t, y, bodies=("obj", "hand"))
    with pytest.raises(DataFileError) as info:
        load_experiment(bad, scenario)
    text = str(info.value)
    assert "column 'body': no body named 'hand' in the scenario" in text
    assert "the scenario's body 'grip' has no samples" in text


def test_identify_table_checked_against_the_scenario(tmp_path):
    path = tmp_path / "fit.toml"
    path.write_text(
        TWO_BODIES
        + '[identify]\nfit = ["stiffness", "mass"]\nconnections = ["obj-hand"]\n'
        'axes = ["x", "roll"]\nbodies = ["grip", "nobody"]\n'
    )
    with pytest.raises(eo.ScenarioError) as info:
        load_scenario(path)
    text = str(info.value)
    assert "[identify], key 'connections': no connection named 'obj-hand'" in text
    assert "[identify], key 'axes': unknown axis 'roll'" in text
    assert "[identify], key 'bodies': no body named 'nobody'" in text
    path.write_text(TWO_BODIES + "[identify]\nmax_iterations = 0\nfit = []\n")
    with pytest.raises(eo.ScenarioError) as info:
        load_scenario(path)
    text = str(info.value)
    assert "[identify], key 'max_iterations': input should be greater than" in text
    assert "[identify], key 'fit'" in text
    path.write_text(
        TWO_BODIES + '[identify]\nfit = ["stiffness", "mass"]\naxes = ["x", "z"]\n'
        'bodies = ["grip"]\nmax_iterations = 7\n'
    )
    scenario = load_scenario(path)
    assert scenario.identify.max_iterations == 7
    from elasticoop._config.identify_settings import fit_selection

    selection = fit_selection(scenario, scenario.identify)
    assert selection.names == (
        "stiffness[obj-grip].x",
        "stiffness[obj-grip].z",
        "mass[grip]",
    )
    stiffness_mask, mass_mask = selection.mask
    np.testing.assert_array_equal(stiffness_mask, [[1, 0, 1, 0, 0, 0]])
    np.testing.assert_array_equal(mass_mask, [False, True])


def test_a_mask_frees_some_entries_of_a_leaf(scenario):
    from elasticoop._identify.parameters import free_parameters

    model = scenario.model
    mask = np.zeros((1, 6), bool)
    mask[0, [0, 2]] = True
    free = free_parameters(
        model, lambda m: (m.stiffness, m.bodies.mass), mask=(mask, None)
    )
    assert free.names == (
        "stiffness[0-1].x",
        "stiffness[0-1].z",
        "bodies.mass[0]",
        "bodies.mass[1]",
    )
    np.testing.assert_allclose(free.current(model), [1e3, 1e3, 1.0, 0.2])
    changed = free.apply(
        model, jnp.asarray(free.unconstrained(np.array([2e3, 3e3, 1.5, 0.3])))
    )
    np.testing.assert_allclose(
        np.asarray(changed.stiffness), [[2e3, 1e3, 3e3, 5.0, 5.0, 5.0]]
    )
    np.testing.assert_allclose(np.asarray(changed.bodies.mass), [1.5, 0.3])
    stderr, _ = free.unflatten(np.array([1.0, 2.0, 3.0, 4.0]))
    np.testing.assert_array_equal(stderr, [[1.0, np.nan, 2.0] + [np.nan] * 3])
    with pytest.raises(ValueError, match="frees no entry"):
        free_parameters(model, lambda m: m.stiffness, mask=np.zeros((1, 6), bool))


def test_savitzky_golay_leaves_out_windows_with_missing_samples():
    ts = np.linspace(0.0, 1.0, 41)
    clean = np.stack([np.sin(3 * ts), ts**2], axis=1)
    gappy = clean.copy()
    gappy[20, 0] = np.nan
    window = 7
    (want,) = savitzky_golay(clean, ts, window, 3, derivs=(1,))
    (got,) = savitzky_golay(gappy, ts, window, 3, derivs=(1,))
    hit = np.zeros(41, bool)
    hit[17:24] = True  # the estimates whose window of 7 holds sample 20
    assert np.all(np.isnan(got[hit, 0]))
    np.testing.assert_allclose(got[~hit, 0], want[~hit, 0], rtol=1e-12)
    np.testing.assert_allclose(got[:, 1], want[:, 1], rtol=1e-12)


# -- unclear errors of the second audit (issue: every case a clear message) -------


def identify_refuses(tmp_path, capsys, data, *words):
    """`elasticoop identify` refuses the data file `data` before fitting: exit 2,
    one message naming the file and `words`, no traceback."""
    from elasticoop._cli import main

    scenario_file = tmp_path / "pair.toml"
    scenario_file.write_text(TWO_BODIES)
    out = tmp_path / "out"
    code = main(["identify", str(scenario_file), str(data), "-o", str(out), "-q"])
    err = capsys.readouterr().err
    assert code == 2, err
    assert f"{data}: " in err, err
    for word in words:
        assert word in err, err
    assert "Traceback" not in err and "internal error" not in err
    assert not out.exists()
    return err


def test_a_5_mb_garbage_header_cell_is_named_not_an_internal_error(tmp_path, capsys):
    # Was: exit 1, "internal error (Error: field larger than field limit
    # (131072)). This is a bug in elasticoop", with a traceback.
    t, y = known_motion()
    path = write_csv(tmp_path / "m.csv", t, y)
    lines = path.read_text().splitlines()
    cells = lines[1].split(",")
    cells[3] = "x" * 5_000_000
    lines[1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    err = identify_refuses(tmp_path, capsys, path, "line 2: not a line of CSV")
    assert "(5000" in err and len(err) < 2000  # the length, not the cell
    # a long cell within the reader's limit: named by its start and length
    cells[3] = "x" * 100_000
    lines[1] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    err = identify_refuses(
        tmp_path, capsys, path, "line 2 (header): cell 4 is not a column name"
    )
    assert "(100000 characters)" in err and len(err) < 2000


def test_a_byte_order_mark_is_read_not_shown_as_an_invisible_character(
    scenario, tmp_path, capsys
):
    # Was: "column '\ufefft', line 1 (header): not a column name of measured
    # data" (the mark invisible in the message).
    t, y = known_motion()
    path = write_csv(tmp_path / "m.csv", t, y, comment=False)
    path.write_bytes(b"\xef\xbb\xbf" + path.read_bytes())
    np.testing.assert_allclose(np.asarray(load_experiment(path, scenario).y), y)
    # one inside the file (two files joined) is named
    lines = path.read_text(encoding="utf-8-sig").splitlines()
    lines[0] = lines[0].replace("obj.y", "\ufeffobj.y")
    path.write_text("\n".join(lines) + "\n")
    identify_refuses(
        tmp_path,
        capsys,
        path,
        "cell 3, '\\ufeffobj.y', holds invisible characters (U+FEFF",
        "byte-order mark",
    )


def test_a_data_cell_of_1e300_is_named_with_file_column_and_line(tmp_path, capsys):
    # Was: the fit started and stopped with "the simulation with sensitivities
    # fails at the start ..." (exit 2), naming no file, column or value.
    t, y = known_motion()
    path = write_csv(tmp_path / "m.csv", t, y)
    lines = path.read_text().splitlines()
    cells = lines[3].split(",")
    cells[2] = "1e300"
    lines[3] = ",".join(cells)
    path.write_text("\n".join(lines) + "\n")
    identify_refuses(
        tmp_path,
        capsys,
        path,
        "column 'obj.y', line 4: 1e+300 lies beyond ±1e+15",
    )
    nc = netcdf(tmp_path / "run.nc", t, np.where(y > 0.5, 1e300, y))
    identify_refuses(tmp_path, capsys, nc, "column 'y', sample", "1e+300 lies beyond")


def test_netcdf_times_that_are_dates_or_milliseconds_are_refused(tmp_path, capsys):
    # Was: times in "seconds since 2000-01-01" were decoded into dates and read as
    # nanoseconds since 1970 (exit 3 from the fit); "ms" was read as seconds.
    import xarray as xr

    t, y = known_motion()
    path = netcdf(tmp_path / "run.nc", t, y)
    for units, words in (
        ("seconds since 2000-01-01", "are not seconds (a date: give the time"),
        ("ms", "units 'ms' are not seconds"),
    ):
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            changed = ds.load()
        changed["time"].attrs["units"] = units
        other = tmp_path / "dated.nc"
        changed.to_netcdf(other, engine="h5netcdf")
        identify_refuses(tmp_path, capsys, other, "column 'time': units", words)


def test_noise_levels_out_of_range_are_named(scenario, tmp_path):
    # Was: accepted: a noise level of 1e-300 weighs its residuals by 1e300, whose
    # squares overflow float64.
    t, y = known_motion()
    sigma = [1e-3] * 12
    sigma[4] = 1e-300
    path = write_csv(tmp_path / "m.csv", t, y, sigma=sigma)
    with pytest.raises(DataFileError, match="column 'obj.theta', line 3") as info:
        load_experiment(path, scenario)
    assert "(sigma): the noise level '1e-300' lies below 1e-15" in str(info.value)


def test_a_file_of_too_many_cells_is_refused_before_it_is_split(
    scenario, tmp_path, monkeypatch
):
    # (a file near the data-file limit of 1 GiB held as Python strings took many
    # times its size in memory before the samples' own limit was checked)
    from elasticoop._config import measured_csv

    t, y = known_motion()
    path = write_csv(tmp_path / "m.csv", t, y)
    monkeypatch.setattr(measured_csv, "MAX_CSV_CELLS", 40)
    monkeypatch.setattr(measured_csv, "_rows", None)  # never reached
    with pytest.raises(DataFileError, match="about 6[0-9] cells, over the limit of 40"):
        load_experiment(path, scenario)


def test_netcdf_without_a_time_coordinate_is_refused(scenario, tmp_path):
    # Was: silently read as the sample numbers, t = 0, 1, 2, ... s (xarray's
    # default index of a dimension without a coordinate).
    import xarray as xr

    t, y = known_motion()
    path = netcdf(tmp_path / "run.nc", t, y)
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        no_time = ds.load().drop_vars("time")
    other = tmp_path / "no_time.nc"
    no_time.to_netcdf(other, engine="h5netcdf")
    with pytest.raises(DataFileError, match="column 'time': missing coordinate"):
        load_experiment(other, scenario)
