"""`simulate` and `Scenario` take their solver settings as one `SimulationOptions`;
the settings one by one still work, with a `DeprecationWarning`."""

import dataclasses

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import small_two_body_model

import elasticoop as eo

MODEL, Y0 = small_two_body_model()
YDOT0 = jnp.zeros_like(Y0).at[1, 2].set(0.5)
TS = jnp.linspace(0.0, 0.02, 3)
OPTIONS = eo.SimulationOptions("tsit5", rtol=1e-7, atol=1e-9, max_steps=500)


def settings(options: eo.SimulationOptions) -> tuple:
    """The fields of `options` (not its `owner`, the name its messages use)."""
    o = options
    return (o.solver, o.rtol, o.atol, o.max_steps, o.gimbal_tol, o.link_tol)


def test_the_defaults():
    """Dopri8 at rtol 1e-9, atol 1e-11: the least work at SciPy's accuracy
    (`benchmarks/defaults.py`, `benchmarks/work_precision.py`)."""
    assert eo.SimulationOptions() == eo.SimulationOptions("dopri8", 1e-9, 1e-11)
    assert eo.SimulationOptions().max_steps == 100_000


@pytest.mark.slow
def test_simulate_takes_options_and_the_old_keywords_with_a_warning():
    new = eo.simulate(MODEL, Y0, YDOT0, TS, options=OPTIONS)
    match = r"simulate\(solver, rtol, atol, max_steps=\.\.\.\) is deprecated"
    with pytest.warns(DeprecationWarning, match=match):
        old = eo.simulate(
            MODEL, Y0, YDOT0, TS, solver="tsit5", rtol=1e-7, atol=1e-9, max_steps=500
        )
    np.testing.assert_array_equal(new.y, old.y)
    assert int(new.n_steps) == int(old.n_steps)
    # a setting given one by one replaces that field of `options`
    with pytest.warns(DeprecationWarning, match=r"options=SimulationOptions\(max_"):
        capped = eo.simulate(
            MODEL, Y0, YDOT0, TS, options=OPTIONS, max_steps=1, throw=False
        )
    assert int(capped.status) == eo.Status.MAX_STEPS_REACHED


def test_a_bad_field_is_named_by_who_was_given_it():
    # built by the user: the class's name (before: "simulate.solver ...")
    with pytest.raises(ValueError, match=r"^SimulationOptions.solver must be one of"):
        eo.SimulationOptions(solver="rk45")
    with pytest.raises(ValueError, match=r"^SimulationOptions.rtol must be a positive"):
        eo.SimulationOptions(rtol=-1.0)
    # text and booleans are not numbers, though float() reads them (the check
    # itself: under the tests' run-time type checks the annotation refuses first)
    from elasticoop._options import _positive

    for value, shown in (("1e-6", "'1e-6'"), (True, "True")):
        with pytest.raises(
            ValueError, match=rf"^S.*rtol must be a positive number, got {shown}"
        ):
            _positive(value, "rtol", "SimulationOptions")
    # a deprecated keyword of `simulate` replacing a field of given options: simulate's
    with pytest.warns(DeprecationWarning):
        with pytest.raises(ValueError, match=r"^simulate.rtol must be a positive"):
            eo.simulate(MODEL, Y0, YDOT0, TS, options=OPTIONS, rtol=-1.0)


def test_simulate_refuses_options_of_another_type():
    with pytest.raises(ValueError, match="simulate.options must be a Simulation"):
        eo.simulate(MODEL, Y0, YDOT0, TS, options={"rtol": 1e-6})


def test_scenario_takes_options_and_the_old_fields_with_a_warning():
    base = dict(name="s", model=MODEL, y_init=Y0, ydot_init=YDOT0, ts=TS, forces=None)
    scenario = eo.Scenario(**base, options=OPTIONS)
    assert scenario.options == OPTIONS
    assert (scenario.solver, scenario.rtol, scenario.atol, scenario.max_steps) == (
        "tsit5", 1e-7, 1e-9, 500,
    )  # fmt: skip
    assert settings(eo.Scenario(**base).options) == settings(eo.SimulationOptions())
    match = r"Scenario\(solver, rtol, atol, max_steps=\.\.\.\) is deprecated"
    with pytest.warns(DeprecationWarning, match=match):
        old = eo.Scenario(**base, solver="tsit5", atol=1e-9, max_steps=500, rtol=1e-7)
    assert settings(old.options) == settings(OPTIONS)
    # what the files and the command line do: replace the options
    faster = dataclasses.replace(
        scenario, options=dataclasses.replace(scenario.options, rtol=1e-6)
    )
    assert faster.rtol == 1e-6 and faster.max_steps == 500
    with pytest.raises(ValueError, match="Scenario.options must be a Simulation"):
        eo.Scenario(**base, options="fast")
