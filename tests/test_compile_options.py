"""The library's programs compile with `FAST_COMPILE` only where they are the
outermost program, and the option changes no result beyond rounding."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import three_body_model, three_body_state

import elasticoop as eo
from elasticoop import _compile_options
from elasticoop._compat import outside_transformations
from elasticoop._compile_options import XLA_DEFAULTS, fast_compile_jit


def test_outside_transformations_is_false_under_every_transformation():
    seen = {}

    def record(x, name):
        seen[name] = outside_transformations()
        return x

    record(1.0, "top")
    jax.jit(lambda x: record(x, "jit"))(1.0)
    jax.vmap(lambda x: record(x, "vmap"))(jnp.ones(2))
    jax.grad(lambda x: record(x, "grad"))(1.0)
    jax.jvp(lambda x: record(x, "jvp"), (1.0,), (1.0,))
    assert seen == {
        "top": True,
        "jit": False,
        "vmap": False,
        "grad": False,
        "jvp": False,
    }


def test_a_fast_compiled_function_runs_at_top_level_and_nested():
    @fast_compile_jit
    def cube(x):
        return x**3

    x = jnp.arange(3.0)
    np.testing.assert_array_equal(cube(x), x**3)
    # nested: JAX refuses compiler options on an inner jit or under grad, so none
    # are passed there
    np.testing.assert_array_equal(jax.jit(cube)(x), x**3)
    np.testing.assert_array_equal(jax.vmap(cube)(x), x**3)
    np.testing.assert_array_equal(jax.grad(lambda x: cube(x).sum())(x), 3 * x**2)


def test_options_go_to_the_outermost_program_only_and_an_unknown_one_falls_back(
    monkeypatch,
):
    # An option XLA does not know shows where options are passed: XLA refuses it.
    monkeypatch.setattr(_compile_options, "FAST_COMPILE", {"xla_no_such_option": 1})
    monkeypatch.setattr(_compile_options, "_options_known", [True])

    @fast_compile_jit
    def square(x):
        return x**2

    x = jnp.arange(3.0)
    np.testing.assert_array_equal(jax.jit(square)(x), x**2)
    assert _compile_options._options_known == [True]  # nested: not passed
    np.testing.assert_array_equal(square(x), x**2)  # refused, then compiled plainly
    assert _compile_options._options_known == [False]
    np.testing.assert_array_equal(square(x + 1), (x + 1) ** 2)


@pytest.mark.slow
def test_the_fast_compiled_simulation_matches_one_compiled_without_options():
    model = three_body_model()
    y0 = three_body_state()
    ydot0 = 0.1 * jnp.ones_like(y0)
    ts = jnp.linspace(0.0, 0.3, 7)

    def run(model):
        return eo.simulate(model, y0, ydot0, ts, rtol=1e-10, atol=1e-12)

    fast = run(model)  # outermost: compiled with FAST_COMPILE
    # inside the caller's jit: the caller's options, here XLA's defaults (the tests
    # otherwise compile with FAST_COMPILE's options, see conftest.py)
    assert set(XLA_DEFAULTS) == set(_compile_options.FAST_COMPILE)
    plain = jax.jit(run, compiler_options=XLA_DEFAULTS)(model)
    assert int(fast.n_steps) == int(plain.n_steps)
    # equal to rounding (the two programs differ in how XLA emits the loops)
    for field in ("y", "ydot"):
        a, b = np.asarray(getattr(fast, field)), np.asarray(getattr(plain, field))
        np.testing.assert_allclose(a, b, rtol=0, atol=1e-11 * np.max(np.abs(b)))


def test_the_options_are_passed_on_the_cpu_only(monkeypatch):
    monkeypatch.setattr(jax, "default_backend", lambda: "cpu")
    assert _compile_options.fast_compile_options() == _compile_options.FAST_COMPILE
    monkeypatch.setattr(jax, "default_backend", lambda: "gpu")
    assert _compile_options.fast_compile_options() == {}
