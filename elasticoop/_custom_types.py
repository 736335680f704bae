"""Shape aliases used across elasticoop (one set of axis names everywhere)."""

from jaxtyping import Array, Float, Int

Scalar = Float[Array, ""]
Vector3 = Float[Array, "3"]
Matrix3 = Float[Array, "3 3"]
BodyState = Float[Array, "6"]
State = Float[Array, "bodies 6"]
StateSeries = Float[Array, "times bodies 6"]
Times = Float[Array, " times"]
Pairs = Int[Array, "connections 2"]
