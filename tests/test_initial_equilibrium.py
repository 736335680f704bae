"""Scenario files that start from their static equilibrium (`[initial] from =
"equilibrium"`) and the pose tracking's `feedforward = "hold"`."""

import copy
import tomllib

import jax.numpy as jnp
import numpy as np
import pytest

import elasticoop as eo
from elasticoop._config import ScenarioError, build_scenario
from elasticoop._examples import example_files, load_example

# static_equilibrium's default tolerances, which the scenario loader uses
EQUILIBRIUM_TOL = 1e-10


@pytest.fixture(scope="module")
def beam_lift():
    return load_example("beam_lift")


@pytest.fixture(scope="module")
def beam_lift_raw():
    return tomllib.loads(example_files()["beam_lift"].read_text(encoding="utf-8"))


def start_accelerations(scenario, y):
    """$\\ddot Y(t_0)$ at rest in `y` under the scenario's forces at the start."""
    ydot = jnp.zeros_like(y)
    applied = scenario.forces(scenario.ts[0], y, ydot)
    applied = jnp.concatenate([jnp.zeros((1, 6)), applied])
    return np.asarray(eo.accelerations(scenario.model, y, ydot, applied)[0])


def test_a_scenario_from_its_equilibrium_starts_at_rest(beam_lift, beam_lift_raw):
    given = np.array(
        [
            [*beam_lift_raw["initial"][b]["position"], 0, np.pi / 2, 0]
            for b in beam_lift.names
        ]
    )
    y = np.asarray(beam_lift.y_init)
    # the grasps stay where the file puts them; the beam hangs below its given pose
    np.testing.assert_allclose(y[1:], given[1:], atol=1e-12)
    assert 0.01 < given[0, 2] - y[0, 2] < 0.2
    assert np.all(np.asarray(beam_lift.ydot_init) == 0)
    # Accelerations at t0 from the equations of motion (not the equilibrium
    # solver): the solve stops at a force imbalance of about tol (1 + |F|), which
    # the smallest generalized inertia turns into an acceleration.
    at_rest = jnp.zeros((3, 6))
    forces = np.asarray(beam_lift.forces(beam_lift.ts[0], jnp.asarray(y), at_rest))
    inertia = min(
        beam_lift.model.bodies.mass.min(), beam_lift.model.bodies.inertia.min()
    )
    bound = 10 * EQUILIBRIUM_TOL * (1 + np.abs(forces).max()) / float(inertia)
    assert np.abs(start_accelerations(beam_lift, jnp.asarray(y))).max() < bound
    # at the poses as given the links carry nothing: the beam falls at g
    falling = start_accelerations(beam_lift, jnp.asarray(given))
    np.testing.assert_allclose(falling[0, 2], -9.81, rtol=1e-9)


def test_hold_feedforward_is_the_holding_force(beam_lift):
    # hanging symmetric in two links, each grasp carries its own weight and half
    # the beam's, and is pulled inwards by the tilted link
    ff = np.asarray(beam_lift.forces.feedforward)
    masses = np.asarray(beam_lift.model.bodies.mass)
    np.testing.assert_allclose(ff[:, 2], (masses[0] / 2 + masses[1:]) * 9.81)
    assert ff[0, 0] < -1.0 and ff[1, 0] > 1.0
    np.testing.assert_allclose(ff[0, 0], -ff[1, 0])


def problems_of(raw) -> list:
    with pytest.raises(ScenarioError) as info:
        build_scenario(raw, "study.toml")
    return info.value.problems


def test_bad_initial_option_and_velocities_are_named(beam_lift_raw):
    raw = copy.deepcopy(beam_lift_raw)
    raw["initial"]["from"] = "rest"
    (problem,) = problems_of(raw)
    assert (problem.table, problem.key) == ("[initial]", "from")
    assert "'rest'" in problem.message and '"equilibrium"' in problem.message
    raw["initial"]["from"] = "equilibrium"
    raw["initial"]["left"]["velocity"] = [0.0, 0.0, 0.1]
    raw["initial"]["beam"]["angle_rates"] = {"degrees": [0.0, 0.0, 5.0]}
    found = {(p.table, p.key) for p in problems_of(raw)}
    assert found == {("[initial.left]", "velocity"), ("[initial.beam]", "angle_rates")}
    raw = copy.deepcopy(beam_lift_raw)
    raw["forces"]["pose_tracking"]["feedforward"] = "holding"
    (problem,) = problems_of(raw)
    assert problem.key == "feedforward" and "'hold'" in problem.message


def test_no_equilibrium_to_start_from_is_a_scenario_problem():
    # one free body under gravity and nothing held: no equilibrium
    raw = {
        "model": {"kind": "immobile", "convention": "rpy"},
        "bodies": [{"name": "stone", "mass": 1.0, "inertia": [1.0, 1.0, 1.0]}],
        "immobile": {"K": [[0.0] * 6] * 6, "D": [[0.0] * 6] * 6},
        "initial": {
            "from": "equilibrium",
            "stone": {"position": [0, 0, 1], "angles": {"radians": [0, 0, 0]}},
        },
        "time": {"stop": 0.1},
    }
    (problem,) = problems_of(raw)
    assert (problem.table, problem.key) == ("[initial]", "from")
    assert "no static equilibrium" in problem.message
    assert "not unique" in problem.message
