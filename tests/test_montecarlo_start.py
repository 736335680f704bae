"""What a study's samples start from: with `initial="equilibrium"` each sample
starts at rest in its own closed loop: every coordinate free under the force law
of the experiment (a PoseTracking controller whose feedforward is a number, the
same for every sample).

Known truth: each sample against `closed_loop_rest` and a single `simulate` run
of its own drawn model, which stays at rest (no lift); a study whose laws have no
spread stays at its nominal state."""

import equinox as eqx
import numpy as np
import pytest
from helpers import three_body_model, three_body_state

import elasticoop as eo
from elasticoop import montecarlo as mc
from elasticoop._analysis import closed_loop_rest

TS = np.linspace(0.0, 0.2, 5)
HELD = np.zeros((3, 6), dtype=bool)
HELD[1:] = True
# the rest state's solver converges to 1e-10: two solvers agree to about that
START_ATOL = 1e-8


def _masses(m):
    return m.bodies.mass


def _stiffness(m):
    return m.stiffness


def _nominal():
    model = three_body_model()
    y0 = np.asarray(three_body_state())
    eq = eo.static_equilibrium(model, y0, HELD)
    # the commanded forces: PD control of the grasps' poses plus a feedforward of
    # the forces that hold them at rest in the nominal system (a scenario's
    # feedforward = "hold"), frozen as numbers; no lift
    y_eq = np.asarray(eq.y)
    control = eo.PoseTracking(
        y_ref=y_eq[1:],
        feedforward=np.asarray(eq.reaction)[1:],
        kp=(400.0, 400.0, 400.0, 5.0, 5.0, 5.0),
        kd=(20.0, 20.0, 20.0, 0.1, 0.1, 0.1),
        height=0.0,
        duration=1.0,
    )
    return model, y_eq, control


def _study(mass_std=0.1, stiffness_std=0.2, **kwargs):
    model, y_eq, hold = _nominal()
    return mc.Study(
        model,
        y_eq,
        np.zeros((3, 6)),
        TS,
        forces=hold,
        parameters=[
            mc.Parameter(
                "mass",
                _masses,
                mc.Normal((2.0, 0.3, 0.25), (mass_std, 0.0, 0.0)),
            ),
            mc.Parameter(
                "stiffness",
                _stiffness,
                mc.LogNormal(0.0, stiffness_std),
                relative=True,
            ),
        ],
        outputs={"trajectory": mc.trajectory()},
        n_samples=3,
        key=11,
        options=eo.SimulationOptions(rtol=1e-10, atol=1e-12),
        **kwargs,
    )


# compiles a study with rest states (tens of seconds on 2 cores)
@pytest.fixture(scope="module")
def results():
    study = _study(initial="equilibrium")
    return study, mc.run_study(study, batch_width=3, progress=False)


@pytest.mark.slow
def test_each_sample_starts_at_rest_in_its_own_equilibrium(results):
    """Before, every sample started from the nominal state, or with its grasps
    held at their commanded poses, where the frozen feedforward does not balance
    the drawn sample's reactions: it moved at once (the study measured its
    start). Now each sample stays at its start."""
    study, ds = results
    model, y_eq, hold = _nominal()
    assert np.all(ds["status"].values == 0)
    starts = ds["trajectory"].isel(time=0).values
    for k in range(study.n_samples):
        drawn = eqx.tree_at(
            lambda m: (m.bodies.mass, m.stiffness),
            model,
            (ds["mass"].values[k], ds["stiffness"].values[k]),
        )
        y_k = np.asarray(closed_loop_rest(drawn, y_eq, hold))
        np.testing.assert_allclose(starts[k], y_k, rtol=0, atol=START_ATOL)
        # the object and the grasps sit elsewhere than the nominal ones: the
        # start follows the draw
        assert np.abs(y_k[0] - y_eq[0]).max() > 1e-4
        assert np.abs(y_k[1:] - y_eq[1:]).max() > 1e-5
        single = eo.simulate(
            drawn, y_k, np.zeros((3, 6)), TS, forces=hold, rtol=1e-10, atol=1e-12
        )
        np.testing.assert_allclose(
            ds["trajectory"].values[k], single.y, rtol=0, atol=START_ATOL
        )
        # no lift: the sample stays at its start
        assert np.abs(np.asarray(single.ydot)).max() < START_ATOL
        np.testing.assert_allclose(
            ds["trajectory"].values[k],
            np.broadcast_to(y_k, single.y.shape),
            rtol=0,
            atol=START_ATOL,
        )


@pytest.mark.slow
def test_a_study_without_spread_stays_at_rest(results):
    """Closed form: the nominal system at rest under the forces that hold it stays
    there, so every sample's trajectory is its start at every time (the same
    compiled code as the study above: only the laws' arrays differ)."""
    _, y_eq, _ = _nominal()
    still = _study(mass_std=0.0, stiffness_std=0.0, initial="equilibrium")
    ds = mc.run_study(still, batch_width=3, progress=False)
    y = ds["trajectory"].values
    np.testing.assert_allclose(y, np.broadcast_to(y_eq, y.shape), atol=START_ATOL)


@pytest.mark.slow
def test_the_start_rule_is_checked_and_recorded():
    study = _study(initial="equilibrium")
    assert study.describe()["initial"] == "equilibrium"
    assert _study().describe()["initial"] == "given"  # the Python default
    with pytest.raises(ValueError, match="ydot_init must be zero"):
        mc.Study(
            three_body_model(),
            three_body_state(),
            np.ones((3, 6)),
            TS,
            parameters=study.parameters,
            outputs={"trajectory": mc.trajectory()},
            n_samples=2,
            initial="equilibrium",
        )
    with pytest.raises(ValueError, match="Study.initial must be one of"):
        _study(initial="rest")
    # constant forces (the controller's feedforward alone) do not hold the
    # grasps: the whole system is free to drift, with no isolated rest state
    model, y_eq, control = _nominal()
    with pytest.raises(ValueError, match="no closed-loop rest state.*singular"):
        mc.Study(
            model,
            y_eq,
            np.zeros((3, 6)),
            TS,
            forces=np.asarray(control.feedforward),
            parameters=study.parameters,
            outputs={"trajectory": mc.trajectory()},
            n_samples=2,
            initial="equilibrium",
        )


def test_solver_settings_are_one_options_object():
    """The scattered spellings warn (they built a SimulationOptions inside)."""
    with pytest.warns(DeprecationWarning, match=r"Study\(rtol=...\) is deprecated"):
        study = mc.Study(
            three_body_model(),
            three_body_state(),
            np.zeros((3, 6)),
            TS,
            parameters=[mc.Parameter("g", lambda m: m.gravity, mc.Uniform(9.7, 9.9))],
            outputs={"trajectory": mc.trajectory()},
            n_samples=2,
            rtol=1e-6,
        )
    default = eo.SimulationOptions()
    assert (study.options.solver, study.rtol, study.atol) == (
        default.solver,
        1e-6,
        default.atol,
    )
    with pytest.raises(ValueError, match="options only, not also as solver"):
        mc.Study(
            three_body_model(),
            three_body_state(),
            np.zeros((3, 6)),
            TS,
            parameters=study.parameters,
            outputs={"trajectory": mc.trajectory()},
            n_samples=2,
            solver="dopri5",
            options=eo.SimulationOptions(),
        )
