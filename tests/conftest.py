import os
import tempfile

import jax

jax.config.update("jax_enable_x64", True)
# No implicit dtype promotion, as in diffrax's tests.
jax.config.update("jax_numpy_dtype_promotion", "strict")

# The command line keeps compiled executables on disk; the tests use a folder of
# their own rather than the user's cache: one per test run, shared by the pytest-xdist
# workers and the processes the tests start, so that a program one of them compiled
# is loaded by the others (JAX writes each entry atomically).
_run = os.environ.get("PYTEST_XDIST_TESTRUNUID")
if _run is None:
    _cache = tempfile.mkdtemp(prefix="elasticoop-")
else:
    _cache = os.path.join(tempfile.gettempdir(), f"elasticoop-tests-{_run}")
    os.makedirs(_cache, exist_ok=True)
os.environ.setdefault("ELASTICOOP_CACHE_DIR", _cache)
