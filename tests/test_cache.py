"""The persistent compilation cache: what JAX stores, equinox's error mode around
it (the one private detail elasticoop relies on, in `elasticoop._compat`), and a
simulation loaded from the cache by a fresh process."""

import json
import subprocess
import sys

import equinox as eqx
import equinox._errors
import jax
import jax.numpy as jnp
import pytest

from elasticoop._cache import compilation_cache, enable_compilation_cache
from elasticoop._compat import (
    SUPPORTED_EQUINOX,
    check_equinox_version,
    equinox_error_mode,
    set_equinox_error_mode,
)

SETTINGS = (
    "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs",
    "jax_persistent_cache_min_entry_size_bytes",
)

# A free body turning slowly: one small simulation (no event on the way).
SCENARIO = """\
name = "free disc"
[model]
kind = "mobile"
convention = "rpy"
gravity = 0.0
[[bodies]]
name = "disc"
mass = 1.0
inertia = [0.01, 0.02, 0.03]
[initial.disc]
position = [0.0, 0.0, 0.0]
angles = { degrees = [0.0, 10.0, 0.0] }
angle_rates = { degrees = [10.0, 20.0, 30.0] }
[time]
stop = 0.2
samples = 5
"""

# Counts the persistent cache's hits and misses of one process.
_COUNTING = """\
import json, sys
import jax, jax.numpy as jnp, equinox as eqx
counts = {"hits": 0, "misses": 0}
def count(event, **kwargs):
    for kind in counts:
        if event == f"/jax/compilation_cache/cache_{kind}":
            counts[kind] += 1
jax.monitoring.register_event_listener(count)
folder = sys.argv[1]
"""

_SIMULATE = (
    _COUNTING
    + """\
import elasticoop
from elasticoop._cache import compilation_cache
with compilation_cache(folder):
    traj = elasticoop.load_scenario(sys.argv[2]).simulate()
    traj.y.block_until_ready()
print(json.dumps(counts))
"""
)

_CHECKED = (
    _COUNTING
    + """\
from elasticoop._compat import equinox_error_mode
jax.config.update("jax_compilation_cache_dir", folder)
jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
def checked_raise(x):
    return eqx.error_if(jnp.sin(x), x > 1e9, "too big")
def checked_nan(x):
    return eqx.error_if(jnp.sin(x), x > 1e9, "too big")
jax.jit(checked_raise)(jnp.ones(3)).block_until_ready()
with equinox_error_mode("nan"):
    jax.jit(checked_nan)(jnp.ones(3)).block_until_ready()
print(json.dumps(counts))
"""
)


def _child(script, *args) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", script, *map(str, args)],
        capture_output=True,
        text=True,
        timeout=600,
    )
    assert out.returncode == 0, out.stderr
    return json.loads(out.stdout.strip().splitlines()[-1])


def _stored(folder, module: str) -> list[str]:
    return [p.name for p in folder.iterdir() if p.name.startswith(module + "-")]


def test_equinox_version_is_supported():
    check_equinox_version()  # the installed equinox
    first, end = SUPPORTED_EQUINOX
    check_equinox_version(".".join(map(str, first)))
    check_equinox_version("0.13.8")
    for outside in ("0.11.9", ".".join(map(str, end)), "1.0.0"):
        with pytest.raises(RuntimeError, match="supports equinox"):
            check_equinox_version(outside)


@pytest.mark.slow
def test_jax_stores_checked_executables_only_in_nan_mode(tmp_path):
    # The reason for `elasticoop._compat`: with equinox's default mode an
    # `equinox.error_if` compiles to a host callback, and JAX does not store the
    # executable. Should this start failing because JAX stores it, the error mode
    # need no longer be switched.
    _child(_CHECKED, tmp_path)
    assert not _stored(tmp_path, "jit_checked_raise")
    assert _stored(tmp_path, "jit_checked_nan")


@pytest.mark.slow
def test_simulation_is_loaded_from_the_cache_by_a_fresh_process(tmp_path):
    scenario = tmp_path / "disc.toml"
    scenario.write_text(SCENARIO)
    cache = tmp_path / "cache"
    first = _child(_SIMULATE, cache, scenario)
    assert first["misses"] > 0
    assert _stored(cache, "jit__solve")  # the solve, runtime checks included
    files = sorted(p.name for p in cache.iterdir())
    second = _child(_SIMULATE, cache, scenario)
    assert second["misses"] == 0 and second["hits"] > 0  # nothing compiled
    assert sorted(p.name for p in cache.iterdir()) == files


def test_error_mode_is_restored_and_does_not_leak(tmp_path):
    saved = {name: getattr(jax.config, name) for name in SETTINGS}
    mode = equinox._errors.EQX_ON_ERROR
    f = eqx.filter_jit(lambda x: eqx.error_if(x, x > 0, "positive"))
    with compilation_cache(tmp_path / "cache") as folder:
        assert folder == tmp_path / "cache" and folder.is_dir()
        assert jax.config.jax_compilation_cache_dir == str(folder)
        assert equinox._errors.EQX_ON_ERROR == "nan"
        assert jnp.isnan(f(jnp.array(1.0)))
    assert equinox._errors.EQX_ON_ERROR == mode
    assert {name: getattr(jax.config, name) for name in SETTINGS} == saved
    # the function traced inside the block raises again outside it
    with pytest.raises(Exception, match="positive"):
        f(jnp.array(1.0))
    with equinox_error_mode("off"):
        assert f(jnp.array(1.0)) == 1.0
    with pytest.raises(ValueError, match="mode must be one of"):
        set_equinox_error_mode("loud")


def test_unusable_folder_changes_nothing(tmp_path):
    saved = {name: getattr(jax.config, name) for name in SETTINGS}
    mode = equinox._errors.EQX_ON_ERROR
    a_file = tmp_path / "file"
    a_file.write_text("")
    with pytest.raises(ValueError, match="must be a folder"):
        with compilation_cache(a_file):
            pass
    with pytest.raises(ValueError, match="must be a folder"):
        enable_compilation_cache(a_file)
    assert {name: getattr(jax.config, name) for name in SETTINGS} == saved
    assert equinox._errors.EQX_ON_ERROR == mode


def test_enable_compilation_cache_switches_the_mode_for_the_process(tmp_path):
    saved = {name: getattr(jax.config, name) for name in SETTINGS}
    mode = equinox._errors.EQX_ON_ERROR
    try:
        assert enable_compilation_cache(tmp_path) == tmp_path
        assert equinox._errors.EQX_ON_ERROR == "nan"
        assert jax.config.jax_compilation_cache_dir == str(tmp_path)
    finally:
        set_equinox_error_mode(mode)
        for name, value in saved.items():
            jax.config.update(name, value)
