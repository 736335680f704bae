"""Scenario files: what they build, and a table of malformed files, each rejected
with a message naming the file, the table and the key."""

import math
import pathlib

import jax.numpy as jnp
import numpy as np
import pytest

import elasticoop as eo
from elasticoop import ImmobileModel, MobileModel, SampledForce
from elasticoop._cli import main
from elasticoop._config import ScenarioError, load_scenario

# A small valid scenario: an object and one grasp, a constant force on the grasp.
TINY = """\
name = "tiny"
[model]
kind = "mobile"
gravity = 9.81
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
velocity = [0.0, 0.0, 0.5]
angle_rates = { degrees = [0.0, 0.0, 30.0] }
[forces.constant]
grip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]
[time]
stop = 0.2
samples = 11
"""

# The same two bodies with Appendix A: K and D from files written by the tests.
IMMOBILE = """\
[model]
kind = "immobile"
convention = "rpy"
[[bodies]]
name = "obj"
mass = 1.0
inertia = [0.01, 0.01, 0.01]
[[bodies]]
name = "grip"
mass = 0.2
inertia = [1e-3, 1e-3, 1e-3]
[immobile]
K = "K.csv"
D = "D.npy"
[initial.obj]
position = [0.0, 0.0, 1.0]
angles = { radians = [0.0, 0.0, 0.0] }
[initial.grip]
position = [0.0, 0.0, 1.1]
angles = { radians = [0.0, 0.0, 0.0] }
[time]
stop = 0.1
"""


def coupling(diagonal):
    block = np.diag(diagonal)
    return np.block([[block, -block], [-block, block]])


def write(tmp_path, text, name="scenario.toml"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.fixture
def immobile_dir(tmp_path):
    np.savetxt(tmp_path / "K.csv", coupling([1e3] * 3 + [5.0] * 3), delimiter=",")
    np.save(tmp_path / "D.npy", coupling([2.0] * 3 + [0.01] * 3))
    return tmp_path


def test_tiny_scenario_builds_what_the_file_says(tmp_path):
    s = load_scenario(write(tmp_path, TINY))
    assert isinstance(s.model, MobileModel)
    assert s.body_names == ("obj", "grip") and s.connection_names == ("obj-grip",)
    # degrees are converted to radians; rates too (deg/s -> rad/s)
    assert float(s.y_init[0, 4]) == math.pi / 2
    np.testing.assert_allclose(s.ydot_init[1], [0, 0, 0.5, 0, 0, math.radians(30)])
    # rest length and rest angles default to the initial (unloaded) configuration
    np.testing.assert_allclose(s.model.rest_length, [0.2])
    np.testing.assert_allclose(s.model.rest_angles, [[0.0, 0.0, 0.0]])
    np.testing.assert_allclose(s.forces.F, [[0, 0, 15.0, 0, 0, 0]])
    np.testing.assert_allclose(s.ts, np.linspace(0, 0.2, 11))
    # no [solver] table: the defaults of simulate, SimulationOptions()
    assert (s.solver, s.rtol, s.atol) == ("dopri8", 1e-9, 1e-11)


def test_rest_length_from_unloaded_tables_or_given(tmp_path):
    text = TINY + (
        "[unloaded.obj]\nposition = [0.0, 0.0, 1.0]\n"
        "angles = { degrees = [0.0, 90.0, 0.0] }\n"
        "[unloaded.grip]\nposition = [0.3, 0.0, 1.0]\n"
        "angles = { degrees = [10.0, 90.0, 0.0] }\n"
    )
    s = load_scenario(write(tmp_path, text))
    np.testing.assert_allclose(s.model.rest_length, [0.3])
    np.testing.assert_allclose(s.model.rest_angles, [[-math.radians(10), 0, 0]])
    given = TINY.replace(
        'bodies = ["obj", "grip"]',
        'bodies = ["obj", "grip"]\nrest_length = 0.25\n'
        "rest_angles = { radians = [0.1, 0.0, 0.0] }",
    )
    s = load_scenario(write(tmp_path, given))
    np.testing.assert_allclose(s.model.rest_length, [0.25])
    np.testing.assert_allclose(s.model.rest_angles, [[0.1, 0, 0]])


def test_constant_force_moves_the_centre_of_mass_as_newton_says(tmp_path):
    # Internal (elastic) forces cancel: M z_c'' = F_z - M g, whatever the springs do.
    s = load_scenario(write(tmp_path, TINY))
    traj = s.simulate()
    masses = np.array([1.0, 0.2])
    z_c = np.asarray(traj.y[:, :, 2]) @ masses / masses.sum()
    vz_c = 0.5 * 0.2 / masses.sum()  # initial momentum of the grasp
    t = np.asarray(traj.ts)
    expected = z_c[0] + vz_c * t + 0.5 * (15.0 / masses.sum() - 9.81) * t**2
    np.testing.assert_allclose(z_c, expected, rtol=0, atol=1e-8)


@pytest.mark.slow
def test_sampled_force_from_csv_is_a_ramp(tmp_path):
    # F_z(t) = c t sampled at 3 times is exact under linear interpolation:
    # z_c(t) = z_c(0) + c t^3 / (6 M) - g t^2 / 2 (zero initial momentum).
    (tmp_path / "f.csv").write_text("t,grip.fz,obj.fx\n0,0,0\n0.1,3,0\n0.2,6,0\n")
    text = TINY.replace(
        "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
        '[forces]\nsamples = "f.csv"',
    ).replace("velocity = [0.0, 0.0, 0.5]\n", "")
    s = load_scenario(write(tmp_path, text))
    assert isinstance(s.forces, SampledForce)
    assert s.forces.F.shape == (3, 2, 6)  # a column on the object: all bodies
    traj = s.simulate()
    masses = np.array([1.0, 0.2])
    z_c = np.asarray(traj.y[:, :, 2]) @ masses / masses.sum()
    t = np.asarray(traj.ts)
    expected = z_c[0] + 30.0 * t**3 / (6 * masses.sum()) - 0.5 * 9.81 * t**2
    np.testing.assert_allclose(z_c, expected, rtol=0, atol=1e-8)


def test_immobile_model_from_csv_and_npy(immobile_dir):
    s = load_scenario(write(immobile_dir, IMMOBILE))
    assert isinstance(s.model, ImmobileModel)
    np.testing.assert_array_equal(s.model.K, coupling([1e3] * 3 + [5.0] * 3))
    np.testing.assert_array_equal(s.model.D, coupling([2.0] * 3 + [0.01] * 3))
    np.testing.assert_array_equal(s.model.y0, s.y_init)  # Y0 defaults to initial
    assert s.forces is None and s.solver == "dopri8"


@pytest.mark.slow
def test_prescribed_hold_and_csv_samples(tmp_path):
    hold = TINY + '[prescribed]\ncoordinates = { grip = "all", obj = ["z"] }\n'
    spec = load_scenario(write(tmp_path, hold)).prescribed
    expected = np.zeros((2, 6), bool)
    expected[1] = True
    expected[0, 2] = True
    np.testing.assert_array_equal(spec.mask, expected)
    assert spec.hold and spec.ts is None
    (tmp_path / "m.csv").write_text("t,grip.z,grip.psi\n0,1.0,0\n0.5,1.1,90\n")
    sampled = TINY + (
        '[prescribed]\ncoordinates = { grip = ["z", "psi"] }\n'
        'motion = { csv = "m.csv", angle_unit = "degrees" }\n'
    )
    s = load_scenario(write(tmp_path, sampled))
    spec = s.prescribed
    assert not spec.hold and spec.values.shape == (2, 2, 6)
    np.testing.assert_allclose(spec.values[:, 1, 2], [1.0, 1.1])
    np.testing.assert_allclose(spec.values[:, 1, 3], [0.0, math.pi / 2])
    # coordinates not in the CSV keep their initial values
    np.testing.assert_allclose(spec.values[1, 1, 4], math.pi / 2)
    np.testing.assert_allclose(spec.values[:, 0], np.broadcast_to(s.y_init[0], (2, 6)))
    # two samples: the natural cubic spline is the straight line between them
    traj = s.simulate()
    t = np.asarray(traj.ts)
    np.testing.assert_allclose(traj.y[:, 1, 2], 1.0 + 0.2 * t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(traj.y[:, 1, 3], math.pi * t, rtol=0, atol=1e-12)
    assert traj.reaction.shape == traj.y.shape
    assert float(np.max(np.abs(traj.reaction[:, 0]))) == 0.0


def test_scenario_error_is_a_value_error_listing_problems(tmp_path):
    bad = TINY.replace("mass = 1.0", "mass = -1.0").replace("stop = 0.2", "stop = 0")
    with pytest.raises(ValueError) as info:
        load_scenario(write(tmp_path, bad))
    err = info.value
    assert isinstance(err, ScenarioError) and len(err.problems) == 2
    assert {p.key for p in err.problems} == {"mass", "stop"}


# (name, edit of the base text, extra files, table, key, words in the message).
# The immobile cases start from IMMOBILE with K.csv and D.npy in place.
MALFORMED = [
    (
        "unknown key",
        ("mass = 0.2", "mass = 0.2\nmas = 1"),
        "[[bodies]] #2 (grip)",
        "mas",
        "unknown key",
    ),
    (
        "unknown top-level table",
        ("[time]", "[output]\nx = 1\n[time]"),
        "(top level)",
        "output",
        "unknown key",
    ),
    (
        "missing body in initial",
        (
            "[initial.grip]\nposition = [0.2, 0.0, 1.0]",
            "[initial.grap]\nposition = [0.2, 0.0, 1.0]",
        ),
        "[initial.grap]",
        "",
        "no body named 'grap'",
    ),
    (
        "negative mass",
        ("mass = 1.0", "mass = -1.0"),
        "[[bodies]] #1 (obj)",
        "mass",
        "greater than 0",
    ),
    (
        "inertia violates triangle inequality",
        ("inertia = [0.01, 0.01, 0.01]", "inertia = [0.01, 0.01, 0.05]"),
        "[[bodies]] #1 (obj)",
        "inertia",
        "triangle",
    ),
    (
        "connection to an unknown body",
        ('bodies = ["obj", "grip"]', 'bodies = ["obj", "gripper"]'),
        "[[connections]] #1",
        "bodies",
        "no body named 'gripper'",
    ),
    (
        "negative stiffness",
        ("stiffness = [1e3,", "stiffness = [-1e3,"),
        "[[connections]] #1",
        "stiffness[0]",
        "greater than or equal to 0",
    ),
    (
        "short damping vector",
        ("damping = [5.0, 5.0, 5.0, 0.05, 0.05, 0.05]", "damping = [5.0, 5.0]"),
        "[[connections]] #1",
        "damping",
        "at least 6",
    ),
    (
        "angles without unit",
        (
            "angles = { degrees = [0.0, 90.0, 0.0] }\n[initial.grip]",
            "angles = [0.0, 90.0, 0.0]\n[initial.grip]",
        ),
        "[initial.obj]",
        "angles",
        "stated unit",
    ),
    (
        "angles in unknown units",
        (
            "angles = { degrees = [0.0, 90.0, 0.0] }\n[initial.grip]",
            "angles = { gradians = [0.0, 90.0, 0.0] }\n[initial.grip]",
        ),
        "[initial.obj]",
        "angles",
        "unknown angle unit 'gradians'",
    ),
    (
        "gimbal lock",
        (
            "angles = { degrees = [0.0, 90.0, 0.0] }\n[initial.grip]",
            "angles = { degrees = [0.0, 0.0, 0.0] }\n[initial.grip]",
        ),
        "[initial.obj]",
        "angles",
        "gimbal lock",
    ),
    (
        "wrong type",
        ("gravity = 9.81", 'gravity = "9.81"'),
        "[model]",
        "gravity",
        "valid number",
    ),
    (
        "unknown model kind",
        ('kind = "mobile"', 'kind = "elastic"'),
        "[model]",
        "kind",
        "'mobile' or 'immobile'",
    ),
    (
        "empty time span",
        ("stop = 0.2", "stop = 0.0"),
        "[time]",
        "stop",
        "empty time span",
    ),
    (
        "too few samples",
        ("samples = 11", "samples = 1"),
        "[time]",
        "samples",
        "greater than or equal to 2",
    ),
    (
        "unknown solver",
        ("[time]", '[solver]\nname = "rk4"\n[time]'),
        "[solver]",
        "name",
        "'tsit5'",
    ),
    (
        "force on an unknown body",
        ("grip = [0.0, 0.0, 15.0", "grap = [0.0, 0.0, 15.0"),
        "[forces.constant]",
        "grap",
        "no body named 'grap'",
    ),
    (
        "two kinds of forces",
        ("[forces.constant]", '[forces]\nsamples = "f.csv"\n[forces.constant]'),
        "[forces]",
        "",
        "exactly one",
    ),
    (
        "bad CSV of forces",
        (
            "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
            '[forces]\nsamples = "bad.csv"',
        ),
        "[forces]",
        "samples",
        "column 'grip.fz', data row 2: not a number: 'heavy'",
    ),
    (
        "CSV shorter than the time span",
        (
            "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
            '[forces]\nsamples = "short.csv"',
        ),
        "[forces]",
        "samples",
        "covers t = 0.0..0.1 s",
    ),
    (
        "CSV with a repeated column",
        (
            "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
            '[forces]\nsamples = "dup.csv"',
        ),
        "[forces]",
        "samples",
        "repeated column names: grip.fz",
    ),
    (
        "CSV with unnamed columns",
        (
            "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
            '[forces]\nsamples = "blank.csv"',
        ),
        "[forces]",
        "samples",
        "column 3 of the header has no name",
    ),
    (
        "CSV of true and false",
        (
            "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
            '[forces]\nsamples = "bool.csv"',
        ),
        "[forces]",
        "samples",
        "column 'grip.fz', data row 1: not a number: 'true'",
    ),
    (
        "CSV column naming no component",
        (
            "[forces.constant]\ngrip = [0.0, 0.0, 15.0, 0.0, 0.0, 0.0]",
            '[forces]\nsamples = "col.csv"',
        ),
        "[forces]",
        "samples",
        "'torque' is not a force component",
    ),
    (
        "prescribed unknown coordinate",
        ("[time]", '[prescribed]\ncoordinates = { grip = ["z", "w"] }\n[time]'),
        "[prescribed.coordinates]",
        "grip",
        "unknown coordinate 'w'",
    ),
    (
        "prescribed motion without angle unit",
        (
            "[time]",
            '[prescribed]\ncoordinates = { grip = ["z"] }\nmotion = { csv = "f.csv" }\n'
            "[time]",
        ),
        "[prescribed.motion]",
        "angle_unit",
        "missing required key",
    ),
    (
        "mobile model given K",
        ("[time]", '[immobile]\nK = "K.csv"\nD = "K.csv"\n[time]'),
        "[immobile]",
        "",
        "kind = 'immobile'",
    ),
]
IMMOBILE_MALFORMED = [
    ("non-symmetric K", "K_asym.csv", "[immobile]", "K", "symmetric"),
    ("K of the wrong size", "K_small.csv", "[immobile]", "K", "12 x 12"),
    (
        "K not positive semidefinite",
        "K_neg.csv",
        "[immobile]",
        "K",
        "positive semidefinite",
    ),
    ("K of full rank", "K_full.csv", "[immobile]", "K", "rank K must be <= 6m = 6"),
    ("K file missing", "K_none.csv", "[immobile]", "K", "not found"),
    ("K file of text", "K_text.csv", "[immobile]", "K", "could not be read"),
]


def _data_files(tmp_path):
    (tmp_path / "f.csv").write_text("t,grip.fz\n0,1\n1,1\n")
    (tmp_path / "bad.csv").write_text("t,grip.fz\n0,1\n0.5,heavy\n1,1\n")
    (tmp_path / "short.csv").write_text("t,grip.fz\n0,1\n0.1,1\n")
    (tmp_path / "col.csv").write_text("t,grip.torque\n0,1\n1,1\n")
    (tmp_path / "dup.csv").write_text("t,grip.fz,grip.fz\n0,1,2\n1,1,2\n")
    (tmp_path / "bool.csv").write_text("t,grip.fz\n0,true\n1,false\n")
    (tmp_path / "blank.csv").write_text("t,grip.fz,,\n0,1,2,3\n1,1,2,3\n")
    np.savetxt(tmp_path / "K.csv", coupling([1e3] * 3 + [5.0] * 3), delimiter=",")
    np.save(tmp_path / "D.npy", coupling([2.0] * 3 + [0.01] * 3))
    good = coupling([1e3] * 3 + [5.0] * 3)
    asym = good.copy()
    asym[0, 1] = 3.0
    np.savetxt(tmp_path / "K_asym.csv", asym, delimiter=",")
    np.savetxt(tmp_path / "K_small.csv", good[:6, :6], delimiter=",")
    np.savetxt(tmp_path / "K_neg.csv", -good, delimiter=",")
    np.savetxt(tmp_path / "K_full.csv", np.eye(12), delimiter=",")
    (tmp_path / "K_text.csv").write_text("a,b\nc,d\n")


def _check_rejected(tmp_path, capsys, text, table, key, words):
    path = write(tmp_path, text, "bad.toml")
    code = main(["check", str(path)])
    err = capsys.readouterr().err
    assert code != 0
    assert str(path) in err
    where = f"table {table}" + (f", key '{key}'" if key else ":")
    assert where in err, err
    assert words in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize(
    "name, edit, table, key, words", MALFORMED, ids=[m[0] for m in MALFORMED]
)
def test_malformed_scenario_is_rejected(
    tmp_path, capsys, name, edit, table, key, words
):
    _data_files(tmp_path)
    old, new = edit
    assert old in TINY, name
    _check_rejected(tmp_path, capsys, TINY.replace(old, new, 1), table, key, words)


@pytest.mark.parametrize(
    "name, k_file, table, key, words",
    IMMOBILE_MALFORMED,
    ids=[m[0] for m in IMMOBILE_MALFORMED],
)
def test_malformed_immobile_matrices_are_rejected(
    tmp_path, capsys, name, k_file, table, key, words
):
    _data_files(tmp_path)
    text = IMMOBILE.replace('K = "K.csv"', f'K = "{k_file}"')
    _check_rejected(tmp_path, capsys, text, table, key, words)


def test_every_problem_is_listed_at_once(tmp_path, capsys):
    bad = (
        TINY.replace("mass = 1.0", "mass = -1.0")
        .replace('bodies = ["obj", "grip"]', 'bodies = ["obj", "gripper"]')
        .replace("stop = 0.2", "stop = 0.0")
        .replace(
            "angles = { degrees = [0.0, 90.0, 0.0] }\nvelocity",
            "angles = { turns = [0.0, 90.0, 0.0] }\nvelocity",
        )
    )
    path = write(tmp_path, bad, "bad.toml")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "4 problems" in err
    for where in (
        "table [[bodies]] #1 (obj), key 'mass'",
        "table [[connections]] #1, key 'bodies'",
        "table [time], key 'stop'",
        "table [initial.grip], key 'angles'",
    ):
        assert where in err, err


def test_not_toml_and_missing_file(tmp_path, capsys):
    path = write(tmp_path, "name = \n[model", "broken.toml")
    assert main(["check", str(path)]) == 2
    err = capsys.readouterr().err
    assert "broken.toml" in err and "not valid TOML" in err and "line 1" in err
    assert main(["check", str(tmp_path / "nowhere.toml")]) == 2
    assert "no such scenario file" in capsys.readouterr().err


def test_default_scenario_comes_from_the_packaged_file():
    from elasticoop._examples import default_scenario, example_files, load_example

    assert "beam_lift" in example_files()
    s = default_scenario()
    file = load_example("beam_lift")
    np.testing.assert_array_equal(s.y_init, file.y_init)
    assert s.ts.shape == (301,) and default_scenario(11).ts.shape == (11,)
    # the feedforward is an equal share of the total weight
    total = float(jnp.sum(s.model.bodies.mass))
    np.testing.assert_allclose(s.forces.feedforward[:, 2], 0.5 * total * 9.81)


def test_pose_tracking_lift_begins_at_the_first_time(tmp_path):
    """With `[time] start = 1`, the minimum-jerk lift starts at t = 1 s: at the
    start the reference is the initial pose, so the force is the feedforward alone
    (the clock ran from t = 0, and the grasps were jerked by a lift already 0.104 m
    up); halfway through the lift, the reference is up by half its height and
    rises at 15/8 h/T (the minimum-jerk rate at s = 1/2)."""
    from elasticoop._examples import example_files

    text = example_files()["beam_lift"].read_text()
    text = text.replace("start = 0.0    # [s]", "start = 1.0").replace(
        "stop = 3.0     # [s]", "stop = 4.0"
    )
    s = load_scenario(write(tmp_path, text))
    force = s.forces
    assert float(force.start) == 1.0 and float(s.ts[0]) == 1.0
    at_start = force(s.ts[0], s.y_init, s.ydot_init)
    np.testing.assert_array_equal(at_start, force.feedforward)
    halfway = force(jnp.asarray(2.0), s.y_init, s.ydot_init)
    h, T = 0.2, 2.0
    expected = force.kp[2] * h / 2 + force.kd[2] * 15 / 8 * h / T
    np.testing.assert_allclose(
        halfway[:, 2] - force.feedforward[:, 2], expected, rtol=1e-12
    )


def test_entries_of_the_wrong_kind_are_named(tmp_path, capsys):
    """An entry of `connections` that is not a table, and an empty K, are problems
    of the file (they raised AttributeError and a reshape error)."""
    not_a_table = TINY.replace('name = "tiny"', 'name = "tiny"\nconnections = [7]')
    block = TINY[TINY.index("[[connections]]") : TINY.index("[initial.obj]")]
    _check_rejected(
        tmp_path,
        capsys,
        not_a_table.replace(block, ""),
        "[[connections]] #1",
        "",
        "valid dictionary",
    )
    _data_files(tmp_path)
    empty = IMMOBILE.replace('K = "K.csv"', "K = []")
    _check_rejected(tmp_path, capsys, empty, "[immobile]", "K", "is empty")


def test_equilibrium_start_holds_a_csv_motion_at_its_first_values(tmp_path):
    """`from = "equilibrium"` with a prescribed motion from a CSV file whose first
    row differs from `[initial]`: the run imposes the CSV's values at the first
    time, so the equilibrium is solved with the grasp there (it was solved at the
    `[initial]` pose: the object started with a net force of a spring stretched
    by 0.1 m)."""
    (tmp_path / "m.csv").write_text("t,grip.z\n0,1.1\n0.5,1.1\n")
    text = TINY.replace(
        "[initial.obj]", '[initial]\nfrom = "equilibrium"\n[initial.obj]'
    )
    text = text.replace("velocity = [0.0, 0.0, 0.5]\n", "").replace(
        "angle_rates = { degrees = [0.0, 0.0, 30.0] }\n", ""
    )
    text += (
        '[prescribed]\ncoordinates = { grip = "all" }\n'
        'motion = { csv = "m.csv", angle_unit = "radians" }\n'
    )
    s = load_scenario(write(tmp_path, text))
    assert float(s.y_init[1, 2]) == 1.1
    y0, _, _ = s.prescribed.motion(s.ts).impose(s.ts[0], s.y_init, s.ydot_init)
    np.testing.assert_array_equal(y0, s.y_init)
    net = -(eo.elastic_forces(s.model, y0) - s.model.gravity_forces())[0]
    np.testing.assert_allclose(net, 0.0, atol=1e-8)


def test_an_unknown_feedforward_word_gets_one_message(tmp_path):
    shipped = pathlib.Path(eo.__file__).parent / "scenarios" / "plate_lift.toml"
    text = shipped.read_text().replace('feedforward = "hold"', 'feedforward = "hld"')
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    (problem,) = info.value.problems
    assert problem.key == "feedforward" and problem.message.endswith("got 'hld'")
    assert "'weight', 'hold', 'none' or a table" in problem.message


def test_an_unknown_key_is_not_offered_as_its_own_correction():
    """`solver = ...` in `[solver]` (whose key is `name`) is a key of another
    table: it was answered "did you mean 'solver'?"."""
    from elasticoop._config.problems import unknown_key_message

    assert "did you mean 'solver'" not in unknown_key_message("solver")
    assert unknown_key_message("mas").endswith("(did you mean 'mass'?)")
