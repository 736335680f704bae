"""Shared test models, states and closed forms (the appendix, with the corrections
of docs/model.md), and the common settings of the physics checks' simulations."""

import functools

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

import elasticoop as eo

CONVENTIONS = ("zxz", "rpy")

# Regular orientations for each convention (away from gimbal lock).
UPRIGHT = {"zxz": (0.0, np.pi / 2, 0.0), "rpy": (0.0, 0.0, 0.0)}


def three_body_state(convention="zxz", spread=0.5, height=1.0):
    """Object at the origin-ish, two grasps at +-spread along x."""
    a = UPRIGHT[convention]
    return jnp.array(
        [
            [0.0, 0.0, height, *a],
            [-spread, 0.0, height, *a],
            [spread, 0.0, height, *a],
        ]
    )


def three_body_model(convention="zxz", damping=True, gravity=9.81, stiffness=None):
    """The 3-body MobileModel used across the tests: object + 2 grasps."""
    bodies = [
        eo.RigidBody(2.0, (0.02, 0.15, 0.16)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.25, (1.5e-3, 2.5e-3, 3e-3)),
    ]
    if stiffness is None:
        stiffness = [
            (800.0, 900.0, 1000.0, 20.0, 25.0, 30.0),
            (700.0, 850.0, 950.0, 22.0, 18.0, 26.0),
        ]
    damp = [(3.0, 2.5, 2.0, 0.05, 0.04, 0.06), (2.0, 3.5, 2.2, 0.03, 0.05, 0.04)]
    if not damping:
        damp = [(0.0,) * 6] * 2
    conns = [
        eo.Connection(0, k + 1, stiffness=stiffness[k], damping=damp[k])
        for k in range(2)
    ]
    model = eo.MobileModel(bodies, conns, gravity=gravity, convention=convention)
    return model.with_unloaded_state(three_body_state(convention))


def zxz_mass_matrix(m, A, B, C, theta, phi):
    """W_i printed in Appendix A."""
    st, ct, sp, cp = np.sin(theta), np.cos(theta), np.sin(phi), np.cos(phi)
    W = np.zeros((6, 6))
    W[0, 0] = W[1, 1] = W[2, 2] = m
    W[3, 3] = st**2 * (A * sp**2 + B * cp**2) + C * ct**2
    W[3, 4] = W[4, 3] = 0.5 * (A - B) * st * np.sin(2 * phi)
    W[3, 5] = W[5, 3] = C * ct
    W[4, 4] = A * cp**2 + B * sp**2
    W[5, 5] = C
    return W


def zxz_wdot_ydot(A, B, C, theta, phi, dpsi, dtheta, dphi):
    """The printed vector Wdot_i ydot_i with correction 3 of docs/model.md (phi row
    restored)."""
    st, ct = np.sin(theta), np.cos(theta)
    s2p, c2p = np.sin(2 * phi), np.cos(2 * phi)
    sp2, cp2 = np.sin(phi) ** 2, np.cos(phi) ** 2
    psi_row = (
        dpsi * dtheta * np.sin(2 * theta) * (A * sp2 + B * cp2 - C)
        + dpsi * dphi * (A - B) * st**2 * s2p
        + dtheta * dphi * st * ((A - B) * c2p - C)
        + 0.5 * dtheta**2 * (A - B) * ct * s2p
    )
    theta_row = (
        0.5 * dpsi * dtheta * (A - B) * ct * s2p
        + dpsi * dphi * (A - B) * st * c2p
        - dtheta * dphi * (A - B) * s2p
    )
    phi_row = -dpsi * dtheta * C * st
    return np.array([0, 0, 0, psi_row, theta_row, phi_row])


def zxz_dT_dy(A, B, C, theta, phi, dpsi, dtheta, dphi):
    """dT_i/dy_i printed in Appendix A."""
    st, ct = np.sin(theta), np.cos(theta)
    s2p, c2p = np.sin(2 * phi), np.cos(2 * phi)
    sp2, cp2 = np.sin(phi) ** 2, np.cos(phi) ** 2
    theta_row = (
        0.5 * dpsi**2 * np.sin(2 * theta) * (A * sp2 + B * cp2 - C)
        + 0.5 * dpsi * dtheta * (A - B) * ct * s2p
        - dpsi * dphi * C * st
    )
    phi_row = (
        0.5 * dpsi**2 * (A - B) * st**2 * s2p
        + dpsi * dtheta * (A - B) * st * c2p
        - 0.5 * dtheta**2 * (A - B) * s2p
    )
    return np.array([0, 0, 0, 0, theta_row, phi_row])


def zxz_w_angular(A, B, C, theta, phi, dpsi, dtheta, dphi):
    """Angular rows of the appendix's w_i (elastic/damping parts excluded), with
    correction 2 of docs/model.md (the missing minus before C in the theta row)."""
    st, ct = np.sin(theta), np.cos(theta)
    s2p, c2p = np.sin(2 * phi), np.cos(2 * phi)
    sp2, cp2 = np.sin(phi) ** 2, np.cos(phi) ** 2
    psi_row = (
        dpsi * dtheta * np.sin(2 * theta) * (A * sp2 + B * cp2 - C)
        + dpsi * dphi * (A - B) * st**2 * s2p
        + dtheta * dphi * st * ((A - B) * c2p - C)
        + 0.5 * dtheta**2 * (A - B) * ct * s2p
    )
    theta_row = (
        -0.5 * dpsi**2 * np.sin(2 * theta) * (A * sp2 + B * cp2 - C)
        + dpsi * dphi * st * ((A - B) * c2p + C)
        - dtheta * dphi * (A - B) * s2p
    )
    phi_row = (
        -0.5 * dpsi**2 * (A - B) * st**2 * s2p
        - dpsi * dtheta * st * ((A - B) * c2p + C)
        + 0.5 * dtheta**2 * (A - B) * s2p
    )
    return np.array([psi_row, theta_row, phi_row])


# `simulate` compiles once per model structure (bodies, connections, convention,
# prescribed mask and motion type), force type, number of output times and solver
# settings; JAX keeps the executable for the session. The physics checks simulate
# through `run_tight`, which fixes all but the model, so that after the first check
# on a model structure the others reuse its compilation.
SAMPLES = 4001
TIGHT = dict(rtol=1e-12, atol=1e-14)


def run_tight(model, y, ydot, t_end, forces=None, **kwargs):
    """`simulate` from t = 0 to `t_end` at SAMPLES output times with TIGHT
    tolerances. The forces are a constant array `(bodies, 6)`: zero without
    `forces`, with a zero object row in front of contact forces `(m, 6)`. The
    keyword arguments (`prescribed`, `throw`) go to `simulate`; differentiable and
    `vmap`-able in every array argument."""
    n = model.n_bodies
    rows = jnp.zeros((n, 6)) if forces is None else jnp.asarray(forces)
    if rows.shape[0] == n - 1:
        rows = jnp.concatenate([jnp.zeros((1, 6), rows.dtype), rows])
    ts = jnp.linspace(0.0, t_end, SAMPLES)
    return eo.simulate(model, y, ydot, ts, forces=rows, **TIGHT, **kwargs)


class Wave(eo.AbstractMotion):
    """Prescribed poses swaying about `y0` (positions and angles); zero amplitude
    holds them still (`hold`), in a run compiled once for both."""

    y0: jax.Array
    amplitude: jax.Array  # (bodies, 6)
    omega: float = 4.0

    def __call__(self, t):
        return self.y0 + self.amplitude * jnp.sin(self.omega * t)


def hold(mask, y):
    """The coordinates in `mask` held at their values in `y`."""
    y = jnp.asarray(y)
    return eo.PrescribedMotion(mask, Wave(y, jnp.zeros_like(y)))


def small_two_body_model():
    """One object and one grasp on a rest-length link (the export and plot tests)."""
    up = UPRIGHT["zxz"]
    bodies = [eo.RigidBody(1.0, (0.01,) * 3), eo.RigidBody(0.2, (1e-3,) * 3)]
    link = eo.Connection(0, 1, (1e3,) * 3 + (5.0,) * 3, (5.0,) * 3 + (0.05,) * 3)
    y0 = jnp.array([[0.0, 0.0, 1.0, *up], [0.2, 0.0, 1.0, *up]])
    return eo.MobileModel(bodies, [link]).with_unloaded_state(y0), y0


SMALL_TS = jnp.linspace(0.0, 0.2, 11)


@functools.cache
def two_body_run():
    """A short run of `small_two_body_model` with a lift force, and the same motion
    viewed through the linearized (Appendix A) model: enough for layout, export and
    plot checks, with one compilation of `simulate`."""
    model, y0 = small_two_body_model()
    ydot0 = jnp.zeros_like(y0).at[1, 2].set(0.5)
    lift = [[0.0, 0.0, 15.0, 0.0, 0.0, 0.0]]
    traj = eo.simulate(model, y0, ydot0, SMALL_TS, forces=lift)
    immobile = eqx.tree_at(lambda t: t.model, traj, eo.linearize_mobile(model, y0))
    return traj, immobile


def readme_command(command, paths, **options):
    """The README's first shell line `elasticoop COMMAND ...` as an argument list
    for `elasticoop._cli.main`, so that the tests run what the README shows: each
    argument is mapped through `paths` (e.g. README's `my_study/x.toml` to a file
    of the test), and each `options` entry replaces the value of the option
    `--name` (`max_iterations` for `--max-iterations`) or appends it."""
    import pathlib
    import re
    import shlex

    readme = pathlib.Path(__file__).resolve().parents[1] / "README.md"
    line = re.search(
        rf"^elasticoop {command} (.*?)(  #.*)?$", readme.read_text(), flags=re.M
    )
    assert line is not None, f"the README shows no 'elasticoop {command}' line"
    argv = [command] + [paths.get(a, a) for a in shlex.split(line.group(1))]
    for name, value in options.items():
        flag = "--" + name.replace("_", "-")
        if flag in argv:
            argv[argv.index(flag) + 1] = str(value)
        else:
            argv += [flag, str(value)]
    return argv
