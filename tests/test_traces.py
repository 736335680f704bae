"""Traced programs kept on disk (`elasticoop._traces`): the static equilibrium
loaded from a stored program is the one traced anew, bit for bit; a program is
stored per structure and static values of the arguments, never used outside the
compilation cache, and a damaged one is traced again."""

import equinox as eqx
import jax.numpy as jnp
import numpy as np
from test_equilibrium import GRASPS, bodies, configuration

import elasticoop as eo
from elasticoop import _traces
from elasticoop._cache import compilation_cache
from elasticoop._traces import FOLDER, stored_program


def model():
    """Rest-length links (the BFGS descent matters) holding a sagging object."""
    conns = [
        eo.Connection(0, 1, [800.0, 900.0, 1000.0, 20.0, 25.0, 30.0], np.zeros(6)),
        eo.Connection(0, 2, [700.0, 850.0, 950.0, 22.0, 18.0, 26.0], np.zeros(6)),
    ]
    return eo.MobileModel(bodies(), conns, gravity=9.81).with_unloaded_state(
        configuration()
    )


def with_object_mass(m, mass):
    return eqx.tree_at(lambda t: t.bodies.mass, m, m.bodies.mass.at[0].set(mass))


def fields(eq):
    return [np.asarray(x) for x in (eq.y, eq.reaction, eq.residual, eq.stiffness)]


def stored(folder):
    return sorted((folder / FOLDER).glob("*.jaxexport"))


def test_stored_equilibrium_is_the_traced_one(tmp_path):
    m, y = model(), configuration()
    traced = eo.static_equilibrium(m, y, GRASPS)
    assert not (tmp_path / FOLDER).exists()
    with compilation_cache(tmp_path):
        first = eo.static_equilibrium(m, y, GRASPS)  # traced and stored
        (path,) = stored(tmp_path)
        _traces._programs.clear()  # as in a fresh process
        loaded = eo.static_equilibrium(m, y, GRASPS)  # loaded from the file
        # other values of the same structure: the same program
        heavier = with_object_mass(m, 2.5)
        again = eo.static_equilibrium(heavier, y, GRASPS)
        assert stored(tmp_path) == [path]
    for a, b, c in zip(fields(traced), fields(first), fields(loaded)):
        np.testing.assert_array_equal(b, a)
        np.testing.assert_array_equal(c, a)
    assert first.steps == traced.steps == loaded.steps
    outside = eo.static_equilibrium(heavier, y, GRASPS)
    for a, b in zip(fields(outside), fields(again)):
        np.testing.assert_array_equal(b, a)
    assert float(again.y[0, 2]) < float(loaded.y[0, 2])  # the heavier sags more


@stored_program
@eqx.filter_jit
def scaled(x, k):
    return (k * x, jnp.sum(x))


def test_one_program_per_static_value_and_a_damaged_one_is_traced_again(tmp_path):
    x = jnp.arange(3.0)
    with compilation_cache(tmp_path):
        (two, _), (three, _) = scaled(x, 2), scaled(x, 3)
        assert len(stored(tmp_path)) == 2
    np.testing.assert_array_equal(two, 2 * x)
    np.testing.assert_array_equal(three, 3 * x)
    path = stored(tmp_path)[0]
    _traces._programs.clear()  # as in a fresh process
    path.write_bytes(b"not a program")
    with compilation_cache(tmp_path):
        again = [scaled(x, k)[0] for k in (2, 3)]
    assert path.read_bytes() != b"not a program"  # stored anew
    np.testing.assert_array_equal(again[0], 2 * x)
    np.testing.assert_array_equal(again[1], 3 * x)


def test_objects_shown_by_their_address_are_not_keys(tmp_path):
    """A static value whose text is its address (here a function) could stand for
    another one in a later process: the program is traced, never stored."""
    calls = []

    @stored_program
    def double(x, fn):
        calls.append(fn)
        return (2 * x,)

    with compilation_cache(tmp_path):
        (out,) = double(jnp.ones(3), lambda v: v)
    np.testing.assert_array_equal(out, 2.0)
    assert len(calls) == 1 and not (tmp_path / FOLDER).exists()


class Factor:
    """A static value of the caller's own code (its text form is faithful, but its
    source is no part of the key)."""

    def __init__(self, k):
        self.k = k

    def __repr__(self):
        return f"Factor({self.k})"

    def __mul__(self, x):
        return self.k * x


def test_code_of_the_callers_own_is_not_a_key(tmp_path):
    """A class or function the key does not cover could change between two
    processes without changing the key: the program is traced, never stored."""
    with compilation_cache(tmp_path):
        (out, _) = scaled(jnp.ones(3), Factor(4))
    np.testing.assert_array_equal(out, 4.0)
    assert not (tmp_path / FOLDER).exists()
