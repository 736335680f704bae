"""Make the measured-data example `elasticoop/scenarios/plate_lift_measured.csv`.

The "measurements" are the example scenario `plate_lift.toml` simulated with grasps
25 % stiffer than the scenario file says (the truth a fit should find), made the way
a real experiment makes them: the experimenter commands what the scenario file
says (the grasp poses, the lift, and the feedforward forces, which `"hold"` derives
from the file's nominal model), while the true system responds with its own
stiffness: it starts at rest in its own static equilibrium (the plate hanging from
the grasps held at their commanded poses), not in the nominal one. The motion is
sampled at the scenario's output times, with Gaussian noise of known level (seeded,
so the file is reproducible) and a few missing samples. Run from the repository
root:

    python examples/make_measured_data.py [OUTPUT.csv]
"""

import pathlib
import sys

import equinox as eqx
import jax.numpy as jnp
import numpy as np

import elasticoop as eo

SCENARIO = pathlib.Path(__file__).parents[1] / "elasticoop/scenarios/plate_lift.toml"
OUTPUT = SCENARIO.with_name("plate_lift_measured.csv")
STIFFNESS_FACTOR = 1.25  # truth = factor x the scenario file's values
DAMPING_FACTOR = 1.0
SIGMA_POSITION = 2e-4  # [m]
SIGMA_ANGLE = 0.02  # [deg]
MISSING_FRACTION = 0.01  # share of the object's samples left empty
SEED = 15


def truth(scenario):
    """The scenario's model with the true stiffness and damping."""
    model = scenario.model
    return eqx.tree_at(
        lambda m: (m.stiffness, m.damping),
        model,
        (STIFFNESS_FACTOR * model.stiffness, DAMPING_FACTOR * model.damping),
    )


def truth_start(scenario, model):
    """The true system's initial state: at rest in its own static equilibrium, the
    grasps held at the commanded poses (those of the scenario), under the
    commanded forces at rest at the start (numbers, as commanded)."""
    y = scenario.y_init
    forces = scenario.forces(scenario.ts[0], y, jnp.zeros_like(y))
    return eo.rest_state(model, y, forces), jnp.zeros_like(y)


def measured_table(scenario):
    """Header cells, the noise row and the sample rows (SI, angles in degrees)."""
    model = truth(scenario)
    y_init, ydot_init = truth_start(scenario, model)
    traj = eo.simulate(
        model,
        y_init,
        ydot_init,
        scenario.ts,
        forces=scenario.forces,
        **scenario.options.kwargs(),
    )
    y = np.array(traj.y)
    y[..., 3:] = np.degrees(y[..., 3:])
    rng = np.random.default_rng(SEED)
    sigma = np.array([SIGMA_POSITION] * 3 + [SIGMA_ANGLE] * 3)
    y = y + sigma * rng.standard_normal(y.shape)
    missing = rng.random(y.shape[:1] + (6,)) < MISSING_FRACTION
    missing[0] = False  # the first sample of every coordinate is kept
    y[:, 0, :][missing] = np.nan
    coords = eo.get_rotation(model.convention).angle_names
    names = ("x", "y", "z", *coords)
    header = ["t"] + [
        f"{b}.{c}" + (" [deg]" if k >= 3 else " [m]")
        for b in scenario.names
        for k, c in enumerate(names)
    ]
    noise = ["sigma"] + [f"{s:g}" for _ in scenario.names for s in sigma]
    rows = [
        [f"{t:.6g}"] + ["" if np.isnan(v) else f"{v:.9g}" for v in sample.reshape(-1)]
        for t, sample in zip(np.asarray(scenario.ts), y)
    ]
    return header, noise, rows


def write(path=OUTPUT):
    scenario = eo.load_scenario(SCENARIO)
    header, noise, rows = measured_table(scenario)
    comment = [
        "# Measured-data example for plate_lift.toml (elasticoop identify).",
        "# Made by examples/make_measured_data.py: plate_lift simulated with "
        f"stiffness x{STIFFNESS_FACTOR:g} and damping x{DAMPING_FACTOR:g}",
        "# of the scenario file's values, starting at rest in its own equilibrium "
        "under the commanded forces,",
        f"# plus Gaussian noise (seed {SEED}; the 'sigma' row gives its levels); "
        f"empty cells are missing samples.",
    ]
    lines = comment + [",".join(header), ",".join(noise)] + [",".join(r) for r in rows]
    pathlib.Path(path).write_text("\n".join(lines) + "\n", encoding="utf-8")
    return path


if __name__ == "__main__":
    print(write(sys.argv[1] if len(sys.argv) > 1 else OUTPUT))
