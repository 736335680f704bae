"""JAX's persistent compilation cache, for command-line runs."""

import contextlib
import os
import pathlib

import jax

from ._compat import check_equinox_version, equinox_error_mode, set_equinox_error_mode

# Where the cache lives unless a path or $ELASTICOOP_CACHE_DIR says otherwise.
DEFAULT_CACHE_DIR = pathlib.Path("~/.cache/elasticoop/jax").expanduser()

# The folder of the cache in use (`None`: none), for the programs `_traces` keeps.
_active: list[pathlib.Path | None] = [None]

_SETTINGS = (
    "jax_compilation_cache_dir",
    "jax_persistent_cache_min_compile_time_secs",
    "jax_persistent_cache_min_entry_size_bytes",
)


def _use_folder(path) -> pathlib.Path:
    """Create the cache folder and point JAX's persistent cache at it."""
    if path is None:
        path = os.environ.get("ELASTICOOP_CACHE_DIR") or DEFAULT_CACHE_DIR
    path = pathlib.Path(path).expanduser()
    if path.exists() and not path.is_dir():
        raise ValueError(f"path must be a folder, got the file {str(path)!r}")
    path.mkdir(parents=True, exist_ok=True)
    jax.config.update("jax_compilation_cache_dir", str(path))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", -1)
    _active[0] = path
    return path


def active_cache_folder() -> pathlib.Path | None:
    """The folder of the compilation cache in use, or `None` when none is."""
    return _active[0]


def enable_compilation_cache(path=None) -> pathlib.Path:
    """Store compiled XLA executables on disk, so that a new process running a
    model of the same shapes loads them instead of compiling again.

    **Arguments:**

    - `path`: the cache folder (created if missing). Default: the environment
      variable `ELASTICOOP_CACHE_DIR`, else `~/.cache/elasticoop/jax`.

    **Returns:** the folder used.

    Every compiled function is cached, however quick its compilation. JAX refuses
    to store an executable that contains a host callback, and `equinox.error_if`
    (used by diffrax, optimistix and lineax for runtime checks inside compiled
    code; `simulate` always contains some) compiles to one; so for the rest of the
    process those checks are switched to equinox's `"nan"` mode (a failed check
    returns NaN instead of raising), as the environment variable
    `EQX_ON_ERROR=nan` would.

    `simulate` behaves the same either way: it reports faults in
    `Trajectory.status` (NaN or inf in traced states or forces included, each
    element of a `vmap` batch on its own), raises `SimulationError` for concrete
    results, and `throw=True` raises under `jit` too (such a function is then not
    stored). Other runtime checks of traced values, such as a `RigidBody` built
    from a traced mass inside `jit`, give NaN instead of an error, for the whole
    batch under `vmap`. Functions compiled before this call keep raising (and are
    not stored): call it before the first simulation. For a limited stretch of a
    program, use `compilation_cache` instead.
    """
    check_equinox_version()
    path = _use_folder(path)
    set_equinox_error_mode("nan")
    return path


@contextlib.contextmanager
def compilation_cache(path=None):
    """`enable_compilation_cache` for the duration of a `with` block: afterwards
    the JAX settings and equinox's error mode are restored, and no function
    compiled inside the block is reused in `"nan"` mode outside it (the command
    line uses this, so that running a command inside a larger program leaves that
    program's settings alone)."""
    check_equinox_version()
    saved = {name: getattr(jax.config, name) for name in _SETTINGS}
    active = _active[0]
    try:
        folder = _use_folder(path)
        with equinox_error_mode("nan"):
            yield folder
    finally:
        for name, value in saved.items():
            jax.config.update(name, value)
        _active[0] = active
