"""Shape aliases used across elasticoop (one set of axis names everywhere)."""

from collections.abc import Sequence
from typing import TYPE_CHECKING, Annotated, Any, TypeAlias, TypeVar

import numpy as np
from jaxtyping import Array, ArrayLike, Bool, Float, Int, Real

Scalar = Float[Array, ""]
Vector3 = Float[Array, "3"]
Vector6 = Float[Array, "6"]
Matrix3 = Float[Array, "3 3"]
# A matrix over the stacked coordinates of all bodies, `(6(m+1), 6(m+1))`.
DofMatrix = Float[Array, "dofs dofs"]
BodyState = Float[Array, "6"]
State = Float[Array, "bodies 6"]
# A state as the public functions of the dynamics accept it: JAX or NumPy.
StateLike = Float[ArrayLike, "bodies 6"]
StateSeries = Float[Array, "times bodies 6"]
Times = Float[Array, " times"]
# The connected pairs of bodies `(i, j)`, a constant of a model's structure.
Pairs = Int[np.ndarray, "connections 2"]
# One value per body, e.g. the kinetic energies `T_i`.
BodyScalars = Float[Array, " bodies"]
# The blocks `W_i` of the block-diagonal mass matrix.
MassBlocks = Float[Array, "bodies 6 6"]
# Generalized forces on the `m` contact bodies, or on all `m + 1` bodies.
Forces = Float[Array, "rows 6"]
# Prescribed coordinates: a concrete bool array `(bodies, 6)`.
Mask = Bool[ArrayLike, "bodies 6"]
# A truth value: a NumPy boolean where computed from concrete values, a JAX one
# where traced (the checks that work both ways, `xp`).
BoolScalar: TypeAlias = Any
# One array per coordinate, `(bodies,)` each (`()` for a single body): the layout in
# which the kinetic energy is evaluated for all bodies at once, elementwise (six
# coordinates, or the three angles).
BodyCoordinate = Float[Array, "*bodies"]
BodyCoordinates: TypeAlias = tuple[BodyCoordinate, ...]
# A time: a Python number or a 0-d array.
TimeLike: TypeAlias = float | int | Real[Array, ""] | Real[np.ndarray, ""]
# Input that a function converts and checks itself (`as_float_array`, with an error
# naming the argument): JAX or NumPy arrays, numbers and nested sequences of numbers.
ArrayInput: TypeAlias = ArrayLike | Sequence[Any]

_T = TypeVar("_T")

# An argument that the function checks itself, raising a `ValueError` that names it:
# type checkers see `Validated[T]` as `T`, while the run-time type checks accept any
# value, so that a wrong one gets the function's own message.
if TYPE_CHECKING:
    Validated: TypeAlias = Annotated[_T, "validated by the function"]
else:

    class Validated:
        def __class_getitem__(cls, item):
            return Any
