"""The benchmark suite at smoke size: the hand-written references against the
library's dynamics, and every benchmark module run once (nothing timed is
asserted; figures at this size mean nothing)."""

import json
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import CONVENTIONS, run_tight, three_body_model, three_body_state

import elasticoop as eo

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"
sys.path.insert(0, str(BENCHMARKS))

import reference  # noqa: E402
import run as runner  # noqa: E402


def _random_state(model, y0, seed):
    rng = np.random.default_rng(seed)
    y = np.asarray(y0) + 0.05 * rng.normal(size=np.shape(y0))
    return y, rng.normal(size=np.shape(y0)), rng.normal(size=np.shape(y0))


def _library(model, y, ydot, force):
    if force.shape[0] == model.n_bodies - 1:
        force = np.concatenate([np.zeros((1, 6)), force])
    out = eo.accelerations(model, jnp.asarray(y), jnp.asarray(ydot), jnp.asarray(force))
    return np.asarray(out[0])


def _check_references(model, y, ydot, force):
    params = reference.numpy_params(model)
    lib = _library(model, y, ydot, force)
    scale = np.max(np.abs(lib))
    by_numpy = reference.numpy_rhs(params, y, ydot, force)
    fast = jax.jit(lambda a, b, f: reference.fast_jax_rhs(params, a, b, f))
    by_jax = np.asarray(fast(jnp.asarray(y), jnp.asarray(ydot), jnp.asarray(force)))
    np.testing.assert_allclose(by_numpy, lib, rtol=0, atol=1e-10 * scale)
    np.testing.assert_allclose(by_jax, lib, rtol=0, atol=1e-10 * scale)


@pytest.mark.parametrize("convention", CONVENTIONS)
@pytest.mark.parametrize("object_row", [False, True])
def test_references_match_library(convention, object_row):
    model = three_body_model(convention)
    y, ydot, force = _random_state(model, three_body_state(convention), seed=1)
    _check_references(model, y, ydot, force if object_row else force[1:])


def test_references_match_library_all_pairs_with_rest_length():
    """Four bodies, every pair connected, links at non-zero rest length (the
    deflection Jacobian's rank-one term is exercised), angles off their rest."""
    up = (0.1, np.pi / 2 - 0.2, 0.3)
    y0 = np.array(
        [[0, 0, 1, *up], [0.4, 0, 1, *up], [0, 0.5, 1.1, *up], [0, 0, 1.6, *up]]
    )
    bodies = [
        eo.RigidBody(1.5, (0.02, 0.03, 0.04)),
        eo.RigidBody(0.3, (2e-3, 3e-3, 4e-3)),
        eo.RigidBody(0.2, (1e-3, 2e-3, 2.5e-3)),
        eo.RigidBody(0.4, (3e-3, 3e-3, 5e-3)),
    ]
    rng = np.random.default_rng(3)
    conns = [
        eo.Connection(i, j, rng.uniform(10, 1e3, 6), rng.uniform(0.1, 5, 6))
        for i in range(4)
        for j in range(i + 1, 4)
    ]
    model = eo.MobileModel(bodies, conns).with_unloaded_state(y0)
    y, ydot, force = _random_state(model, y0, seed=4)
    _check_references(model, y, ydot, force[1:])


def test_solve_ivp_reference_matches_simulate():
    """SciPy's integration of the NumPy right-hand side against `simulate`."""
    model = three_body_model()
    y0 = three_body_state().at[1, :3].add(jnp.array([-0.01, 0.005, 0.008]))
    ydot0 = jnp.zeros_like(y0).at[0].set(jnp.array([0.1, -0.1, 0.2, 0.3, -0.2, 0.1]))
    lift = np.zeros((2, 6))
    lift[:, 2] = 3.0
    ours = run_tight(model, y0, ydot0, 0.05, forces=lift)
    theirs = reference.solve_ivp_mobile(
        model, y0, ydot0, ours.ts, force=lift, rtol=1e-10, atol=1e-12, method="DOP853"
    )
    np.testing.assert_allclose(np.asarray(ours.y), theirs, rtol=0, atol=1e-8)
    assert np.max(np.abs(theirs[-1] - theirs[0])) > 1e-3  # it did move


@pytest.mark.slow
def test_suite_at_smoke_size(tmp_path):
    out = tmp_path / "results.json"
    mine = ["rhs", "scaling"]
    assert runner.main(["--quick", "--json", str(out), "--only", *mine]) == 0
    results = json.loads(out.read_text())
    bench = results["benchmarks"]
    for name in mine:
        assert "error" not in bench[name], bench[name].get("error")
    for row in bench["rhs"]["rows"]:
        assert row["library_over_fast"] > 0
    assert [r["m"] for r in bench["scaling"]["star"]["rows"]] == [1, 4]


# A fresh process; the fast tests of the compilation cache are in test_cache.py.
@pytest.mark.slow
def test_compilation_cache_in_fresh_process(tmp_path):
    """`enable_compilation_cache` stores executables, including one that uses
    `equinox.error_if` (a host callback in the default mode), on disk."""
    script = (
        "import sys, jax, jax.numpy as jnp, equinox as eqx\n"
        "from elasticoop._cache import enable_compilation_cache\n"
        "enable_compilation_cache(sys.argv[1])\n"
        "f = jax.jit(lambda x: eqx.error_if(jnp.sin(x), x > 1e9, 'too big'))\n"
        "print(float(f(jnp.ones(3))[0]))\n"
    )
    cache = tmp_path / "cache"
    subprocess.run([sys.executable, "-c", script, str(cache)], check=True)
    assert any("jit__lambda" in p.name for p in cache.iterdir())
    bad = tmp_path / "file"
    bad.write_text("")
    from elasticoop._cache import enable_compilation_cache

    with pytest.raises(ValueError, match="must be a folder"):
        enable_compilation_cache(bad)
