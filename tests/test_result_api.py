"""What a user does with results: the trajectories of a batch one by one and
their energies per element, a scenario run over other times or another model, and
the applied force of a run handed to the netCDF converter as `simulate` takes it."""

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import three_body_model, three_body_state

import elasticoop as eo

MODEL = three_body_model()
Y0 = three_body_state()
LIFT = np.zeros((2, 6))
LIFT[:, 2] = 12.0
TS = jnp.linspace(0.0, 0.02, 3)


def _run(stiffness, ts=TS):
    model = eqx.tree_at(lambda m: m.stiffness, MODEL, stiffness)
    return eo.simulate(model, Y0, jnp.zeros_like(Y0), ts, forces=LIFT)


@pytest.mark.slow  # ~11 s: compiles the batch loop and each energy, batched and not
def test_a_batch_is_indexed_and_its_energies_are_per_element():
    stiffness = jnp.stack([MODEL.stiffness, 1.5 * MODEL.stiffness])
    batch = jax.vmap(_run)(stiffness)
    for k in range(2):
        one = _run(stiffness[k])
        np.testing.assert_allclose(batch[k].y, one.y, rtol=1e-9, atol=1e-12)
        for method in ("kinetic_energy", "elastic_energy", "energy_residual"):
            np.testing.assert_allclose(
                getattr(batch, method)()[k],
                getattr(batch[k], method)(),
                rtol=1e-12,
                atol=1e-12,
            )
        assert batch[k].message() == "the simulation reached the final time"
    assert batch.elastic_wrench().shape == (2, len(TS), 2, 6)
    assert batch[1:].ts.shape == (1, len(TS))
    with pytest.raises(ValueError, match=r"take one with traj\[i\]"):
        batch.message()
    with pytest.raises(TypeError, match="no batch axis"):
        batch[0][0]


def test_scenario_runs_override_the_times_and_the_model():
    lift = eo.ConstantForce(LIFT)
    scenario = eo.Scenario("lift", MODEL, Y0, jnp.zeros_like(Y0), TS, forces=lift)
    longer = jnp.linspace(0.0, 0.03, 4)
    run = scenario.simulate(ts=longer)
    np.testing.assert_array_equal(run.ts, longer)
    stiffer = eqx.tree_at(lambda m: m.stiffness, MODEL, 1.5 * MODEL.stiffness)
    np.testing.assert_allclose(
        scenario.simulate(model=stiffer).y, _run(1.5 * MODEL.stiffness).y, rtol=1e-12
    )


def test_the_applied_force_may_be_an_array():
    traj = _run(MODEL.stiffness)
    ds = eo.trajectory_to_xarray(traj, forces=LIFT)
    applied = ds["applied_force"].values
    np.testing.assert_array_equal(applied[:, 1:], np.broadcast_to(LIFT, (3, 2, 6)))
    np.testing.assert_array_equal(applied[:, 0], 0.0)  # no row for the object
    with pytest.raises(ValueError, match=r"trajectory_to_xarray: forces must give"):
        eo.trajectory_to_xarray(traj, forces=np.zeros((4, 6)))
    # the method on the result takes what the function takes
    named = traj.to_xarray(
        body_names=["beam", "left", "right"],
        connection_names=["beam-left", "beam-right"],
        attrs={"run": "lift"},
        forces=LIFT,
    )
    np.testing.assert_array_equal(named["applied_force"].values, applied)
    assert list(named["connection"].values) == ["beam-left", "beam-right"]
    assert named.attrs["run"] == "lift"


def test_a_traced_model_out_of_range_is_reported_not_simulated():
    """Negative stiffness or mass reach `simulate` only traced (the constructors
    refuse them): the element is flagged, the others of the batch are untouched."""
    stiffness = jnp.stack([MODEL.stiffness, -MODEL.stiffness])
    batch = jax.vmap(_run)(stiffness)
    assert [eo.Status(int(s)) for s in batch.status] == [
        eo.Status.SUCCESS,
        eo.Status.INVALID_MODEL,
    ]
    np.testing.assert_allclose(
        batch[0].y, _run(MODEL.stiffness).y, rtol=1e-9, atol=1e-12
    )
    assert "constructor refuses" in batch[1].message()
    heavy = jax.jit(
        lambda m: (
            eo.simulate(
                eqx.tree_at(lambda x: x.bodies.mass, MODEL, m),
                Y0,
                jnp.zeros_like(Y0),
                TS,
            ).status
        )
    )
    assert int(heavy(-MODEL.bodies.mass)) == eo.Status.INVALID_MODEL
