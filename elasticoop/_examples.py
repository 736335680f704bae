"""The example scenarios shipped with elasticoop, and the built-in one (the main
job: `python -m elasticoop`)."""

import importlib.resources
from importlib.resources.abc import Traversable

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._config import load_scenario
from ._custom_types import Validated
from ._scenario import Scenario

DEFAULT_EXAMPLE = "beam_lift"


STUDY_SUFFIX = ".study.toml"


def example_files() -> dict[str, Traversable]:
    """The example scenarios shipped with elasticoop: name -> TOML file (a
    `importlib.resources` traversable)."""
    folder = importlib.resources.files("elasticoop") / "scenarios"
    return {
        f.name[: -len(".toml")]: f
        for f in sorted(folder.iterdir(), key=lambda f: f.name)
        if f.name.endswith(".toml") and not f.name.endswith(STUDY_SUFFIX)
    }


def example_studies() -> dict[str, Traversable]:
    """The example Monte Carlo study files shipped with elasticoop (named
    `<name>.study.toml`, beside the scenarios they vary): name -> TOML file."""
    folder = importlib.resources.files("elasticoop") / "scenarios"
    return {
        f.name[: -len(STUDY_SUFFIX)]: f
        for f in sorted(folder.iterdir(), key=lambda f: f.name)
        if f.name.endswith(STUDY_SUFFIX)
    }


def load_example(name: str) -> Scenario:
    """Load a packaged example scenario by name (see `example_files()`)."""
    files = example_files()
    if name not in files:
        raise ValueError(f"no example scenario {name!r}; examples: {sorted(files)}")
    with importlib.resources.as_file(files[name]) as path:
        return load_scenario(path)


def default_scenario(n_output: Validated[int] = 301) -> Scenario:
    """Two manipulators lift a 1 m, 2 kg beam by 0.2 m in 2 s through elastic grasps
    at its ends (3 bodies, 2 connections, ZXZ angles at $\\theta = \\pi/2$, so the
    body x axis is the beam's axis), then hold it for 1 s; read from the packaged
    `scenarios/beam_lift.toml`. `n_output` evenly spaced output samples."""
    if isinstance(n_output, bool) or not isinstance(n_output, int | np.integer):
        raise ValueError(
            f"n_output must be an integer number of output samples, got "
            f"{n_output!r} ({type(n_output).__name__})"
        )
    if n_output < 2:
        raise ValueError(
            f"n_output must be at least 2 (the start and the end of the run), got "
            f"{n_output}"
        )
    scenario = load_example(DEFAULT_EXAMPLE)
    if n_output != scenario.ts.shape[0]:
        ts = jnp.linspace(scenario.ts[0], scenario.ts[-1], n_output)
        scenario = eqx.tree_at(lambda s: s.ts, scenario, ts)
    return scenario
