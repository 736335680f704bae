import gc
import os
import shutil
import tempfile

# Compile the tests' own programs as the library compiles its outermost ones
# (`elasticoop._compile_options.FAST_COMPILE`: XLA's CPU fusion emitters off and
# its backend optimisation level 1 of 3), which shortens compilation, most of a
# test's time (`benchmarks/compile_options.py`). Set before JAX starts its backend,
# which reads the flags once (importing elasticoop does not start it); the processes
# the tests start inherit them. An option already in `XLA_FLAGS` is left as it is.
from elasticoop._compile_options import FAST_COMPILE

_flags = os.environ.get("XLA_FLAGS", "")
for _name, _value in FAST_COMPILE.items():
    if f"--{_name}" not in _flags:
        _flags += f" --{_name}={str(_value).lower()}"
os.environ["XLA_FLAGS"] = _flags.strip()

import jax  # noqa: E402
import pytest  # noqa: E402

jax.config.update("jax_enable_x64", True)
# No implicit dtype promotion, as in diffrax's tests.
jax.config.update("jax_numpy_dtype_promotion", "strict")
# No implicit rank promotion (broadcasting must be written out), as in diffrax's tests.
jax.config.update("jax_numpy_rank_promotion", "raise")

# The command line keeps compiled executables on disk; the tests use a folder of
# their own rather than the user's cache: one per test run, made by the process that
# imports this first (pytest, or pytest-xdist's controller) and inherited through
# the environment by the pytest-xdist workers and the processes the tests start, so
# that a program one of them compiled is loaded by the others (JAX writes each entry
# atomically). The process that made it removes it when the run ends.
_own_cache = None
if "ELASTICOOP_CACHE_DIR" not in os.environ:
    _own_cache = tempfile.mkdtemp(prefix="elasticoop-tests-")
    os.environ["ELASTICOOP_CACHE_DIR"] = _own_cache


# A pytest-xdist worker reports that it finished in its own `pytest_sessionfinish`
# (after every other implementation); the controller then shuts it down and gives
# it 5 s to exit before execnet sends it SIGINT, whose KeyboardInterrupt, landing in
# a garbage-collection callback (JAX's `_xla_gc_callback`, a WeakSet's), prints a
# stray traceback at the end of a passing run. Freeing JAX's compiled programs
# (thousands of them in a worker) and collecting before that report leaves the
# worker little to free on its way out.
@pytest.hookimpl(trylast=True)
def pytest_sessionfinish(session, exitstatus):
    if os.environ.get("PYTEST_XDIST_WORKER"):
        jax.clear_caches()
        gc.collect()
    if _own_cache is not None:
        shutil.rmtree(_own_cache, ignore_errors=True)
