import os
import tempfile

import jax

jax.config.update("jax_enable_x64", True)
# No implicit dtype promotion, as in diffrax's tests.
jax.config.update("jax_numpy_dtype_promotion", "strict")

# The command line keeps compiled executables on disk; the tests use a folder of
# their own rather than the user's cache.
os.environ.setdefault("ELASTICOOP_CACHE_DIR", tempfile.mkdtemp(prefix="elasticoop-"))
