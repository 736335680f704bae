"""The built-in scenario: two manipulators carry a beam through elastic grasps."""

import math

import equinox as eqx
import jax.numpy as jnp

from ._body import RigidBody
from ._forces import AbstractForce
from ._models import Connection, MobileModel

LIFT_HEIGHT = 0.2  # [m]
LIFT_TIME = 2.0  # [s]
SIM_TIME = 3.0  # [s]


def minimum_jerk(s):
    """$10s^3 - 15s^4 + 6s^5$ on $[0, 1]$, held at 0 and 1 outside."""
    s = jnp.clip(s, 0.0, 1.0)
    return s**3 * (10.0 - 15.0 * s + 6.0 * s**2)


class PoseTracking(AbstractForce):
    """Manipulators as PD controllers on the grasp poses plus a weight feedforward.

    Grasp body $i$ is driven towards $Y_{i}^{ref}(t) = Y_{i}(0) + h\\,s(t/T)\\,e_z$
    ($s$ the minimum-jerk profile):
    $F_i = F^{ff} + K_p (Y_i^{ref} - Y_i) + K_d (\\dot Y_i^{ref} - \\dot Y_i)$,
    gains per coordinate (translations [N/m], Euler angles [N m/rad]).
    """

    y_ref: jnp.ndarray  # (m, 6) initial grasp poses
    feedforward: jnp.ndarray  # (m, 6)
    kp: jnp.ndarray  # (6,)
    kd: jnp.ndarray  # (6,)
    height: float
    duration: float

    def __call__(self, t, y, ydot):
        s = minimum_jerk(t / self.duration)
        tau = jnp.clip(t / self.duration, 0.0, 1.0)
        rate = 30.0 * tau**2 * (1.0 - tau) ** 2 / self.duration
        lift = jnp.array([0.0, 0.0, 1.0, 0.0, 0.0, 0.0])
        ref = self.y_ref + self.height * s * lift
        ref_rate = self.height * rate * lift
        grasps, rates = y[1:], ydot[1:]
        return (
            self.feedforward + self.kp * (ref - grasps) + self.kd * (ref_rate - rates)
        )


class Scenario(eqx.Module):
    """A complete simulation set-up: model, initial state, output times, forces."""

    name: str = eqx.field(static=True)
    model: MobileModel
    y_init: jnp.ndarray
    ydot_init: jnp.ndarray
    ts: jnp.ndarray
    forces: AbstractForce | None


def default_scenario(n_output: int = 301) -> Scenario:
    """Two manipulators lift a 1 m, 2 kg beam by 0.2 m in 2 s through elastic grasps
    at its ends (3 bodies, 2 connections, ZXZ angles at $\\theta = \\pi/2$, so the
    body x axis is the beam's axis), then hold it for 1 s."""
    beam = RigidBody(2.0, (0.004, 0.1687, 0.1687))
    grasp = RigidBody(0.3, (1.2e-3, 1.2e-3, 1.2e-3))
    upright = (0.0, math.pi / 2, 0.0)
    y_init = jnp.array(
        [
            [0.0, 0.0, 1.0, *upright],
            [-0.5, 0.0, 1.0, *upright],
            [0.5, 0.0, 1.0, *upright],
        ]
    )
    stiffness = (2.0e4, 2.0e4, 2.0e4, 40.0, 40.0, 40.0)
    damping = (60.0, 60.0, 60.0, 0.4, 0.4, 0.4)
    model = MobileModel(
        [beam, grasp, grasp],
        [Connection(0, 1, stiffness, damping), Connection(0, 2, stiffness, damping)],
        gravity=9.81,
    ).with_unloaded_state(y_init)
    total_mass = float(jnp.sum(model.bodies.mass))
    feedforward = jnp.zeros((2, 6)).at[:, 2].set(0.5 * total_mass * model.gravity)
    forces = PoseTracking(
        y_ref=y_init[1:],
        feedforward=feedforward,
        kp=jnp.array([4.0e3, 4.0e3, 4.0e3, 20.0, 20.0, 20.0]),
        kd=jnp.array([80.0, 80.0, 80.0, 0.5, 0.5, 0.5]),
        height=LIFT_HEIGHT,
        duration=LIFT_TIME,
    )
    return Scenario(
        name="two-arm beam lift",
        model=model,
        y_init=y_init,
        ydot_init=jnp.zeros_like(y_init),
        ts=jnp.linspace(0.0, SIM_TIME, n_output),
        forces=forces,
    )
