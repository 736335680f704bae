"""Energy: conservation, dE/dt = -2R, and the work-energy balance with forces."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import SAMPLES, TIGHT, run_tight, three_body_model, three_body_state
from scipy.integrate import simpson

import elasticoop as eo

# The runs use `run_tight`'s settings (helpers): SAMPLES = 4001 output times and
# TIGHT tolerances, rtol = 1e-12.
# Conservation: rtol <= 1e-10 integration keeps the drift far below 1e-8.
CONSERVATION_RTOL = 1e-8
# Finite-difference dE/dt (4th-order stencil, dt = 0.5 s / 4000 = 1.25e-4 s, modes
# up to ~150 rad/s).
POWER_RTOL = 1e-5
# Work by Simpson's rule on 4001 samples against the solver's energy change.
WORK_RTOL = 1e-6


def _perturbed(convention="zxz"):
    y = three_body_state(convention)
    y = y.at[1, :3].add(jnp.array([-0.02, 0.01, 0.015]))
    y = y.at[2, 3:].add(jnp.array([0.05, -0.03, 0.04]))
    ydot = jnp.zeros_like(y).at[0].set(jnp.array([0.1, -0.2, 0.3, 0.5, -0.4, 0.3]))
    return y, ydot


@pytest.mark.parametrize(
    "convention", ["zxz", pytest.param("rpy", marks=pytest.mark.slow)]
)
def test_energy_conserved_without_damping_or_forces(convention):
    model = three_body_model(convention, damping=False)
    y, ydot = _perturbed(convention)
    traj = run_tight(model, y, ydot, 2.0)  # ~20 periods of the slowest link mode
    energy = np.asarray(traj.total_energy())
    mechanical = float(traj.kinetic_energy()[0] + traj.elastic_energy()[0])
    drift = np.max(np.abs(energy - energy[0])) / mechanical
    assert drift < CONSERVATION_RTOL
    assert float(jnp.max(jnp.abs(traj.dissipated))) == 0.0


def _fourth_order_derivative(x, dt):
    return (x[:-4] - 8 * x[1:-3] + 8 * x[3:-1] - x[4:]) / (12 * dt)


def test_energy_rate_equals_minus_dissipated_power():
    model = three_body_model(damping=True)
    y, ydot = _perturbed()
    traj = run_tight(model, y, ydot, 0.5)
    dt = float(traj.ts[1] - traj.ts[0])
    rate = _fourth_order_derivative(np.asarray(traj.total_energy()), dt)
    power = np.asarray(traj.dissipated_power())[2:-2]
    assert np.max(power) > 1.0  # the dampers really work
    assert np.max(np.abs(rate + power)) < POWER_RTOL * np.max(power)


def _forces_cases():
    F = np.zeros((2, 6))
    F[0, :3] = (3.0, -2.0, 25.0)
    F[1] = (-1.0, 4.0, 20.0, 0.2, -0.1, 0.3)
    ts = np.linspace(0.0, 0.5, 11)
    samples = np.stack([F * np.cos(7 * t) for t in ts])

    def feedback(t, y, ydot):
        # a spring-damper pulling the grasps to their initial heights
        return (
            jnp.zeros((2, 6))
            .at[:, 2]
            .set(-50.0 * (y[1:, 2] - 1.0) - 2.0 * ydot[1:, 2] + 15.0)
        )

    return {
        "constant": eo.ConstantForce(F),
        "sampled": eo.SampledForce(ts, samples),
        "feedback": eo.FeedbackForce(feedback),
        "object_disturbance": eo.ConstantForce(np.concatenate([F[:1], F])),
    }


FORCES = _forces_cases()


# The constant forces share one compiled run (`run_tight`); the others compile
# their own (SampledForce is simulated in the fast tests of scenario files).
@pytest.mark.parametrize(
    "name",
    [
        "constant",
        pytest.param("sampled", marks=pytest.mark.slow),
        pytest.param("feedback", marks=pytest.mark.slow),
        "object_disturbance",
    ],
)
def test_work_energy_balance_with_forces(name):
    force = FORCES[name]
    model = three_body_model(damping=True)
    y, ydot = _perturbed()
    if isinstance(force, eo.ConstantForce):
        traj = run_tight(model, y, ydot, 0.5, forces=force.F)
    else:
        samples = jnp.linspace(0.0, 0.5, SAMPLES)
        traj = eo.simulate(model, y, ydot, samples, forces=force, **TIGHT)
    ts = traj.ts
    # Independent quadrature of the power F . Ydot and of 2R along the samples.
    applied = np.asarray(
        jax.vmap(lambda t, yy, vv: eo._forces.pad_to_bodies(force(t, yy, vv), 3))(
            ts, traj.y, traj.ydot
        )
    )
    power_in = np.sum(applied * np.asarray(traj.ydot), axis=(1, 2))
    work = simpson(power_in, x=np.asarray(ts))
    lost = simpson(np.asarray(traj.dissipated_power()), x=np.asarray(ts))
    energy = np.asarray(traj.total_energy())
    scale = max(abs(work), abs(lost), 1.0)
    assert abs(energy[-1] - energy[0] - work + lost) < WORK_RTOL * scale
    # and the solver's own accounting agrees
    assert abs(float(traj.work[-1]) - work) < WORK_RTOL * scale
    assert float(jnp.max(jnp.abs(traj.energy_residual()))) < WORK_RTOL * scale
