"""What the quantity names of a study file select: the model or force leaf a
`[[parameters]]` entry varies, and the `Output` an `[[outputs]]` entry keeps."""

import dataclasses
from collections.abc import Callable

from ..montecarlo import (
    Output,
    elastic_force,
    final_pose_error,
    max_deflection,
    object_pose,
    peak_elastic_force,
    peak_elastic_force_rise,
    trajectory,
)


@dataclasses.dataclass(frozen=True)
class Quantity:
    """A leaf of the scenario a study may vary.

    - `target`, `where`: as in `montecarlo.Parameter` (`where` a module-level
      function, so that two loads of a study file give equal parameters).
    - `dims`: the leaf's axes: `body`, `connection`, `coordinate` (the six
      coordinates of the convention) or `inertia_axis` (A, B, C).
    - `unit`: the unit of `absolute_spread`.
    - `needs`: `"mobile"` (connections of a mobile model), `"pose_tracking"`
      (`[forces.pose_tracking]`) or `None`.
    - `sign`: `"positive"`, `"nonnegative"` or `None`: what every drawn value
      must be.
    """

    target: str
    where: Callable
    dims: tuple[str, ...]
    unit: str
    needs: str | None
    sign: str | None


def _mass(m):
    return m.bodies.mass


def _inertia(m):
    return m.bodies.inertia


def _stiffness(m):
    return m.stiffness


def _damping(m):
    return m.damping


def _rest_length(m):
    return m.rest_length


def _gravity(m):
    return m.gravity


def _kp(f):
    return f.kp


def _kd(f):
    return f.kd


def _lift_height(f):
    return f.height


def _lift_time(f):
    return f.duration


_PER_AXIS = "N/m or N m/rad per axis"
QUANTITIES = {
    "mass": Quantity("model", _mass, ("body",), "kg", None, "positive"),
    "inertia": Quantity(
        "model", _inertia, ("body", "inertia_axis"), "kg m^2", None, "positive"
    ),
    "stiffness": Quantity(
        "model",
        _stiffness,
        ("connection", "coordinate"),
        _PER_AXIS,
        "mobile",
        "nonnegative",
    ),
    "damping": Quantity(
        "model",
        _damping,
        ("connection", "coordinate"),
        "N s/m or N m s/rad per axis",
        "mobile",
        "nonnegative",
    ),
    "rest_length": Quantity(
        "model", _rest_length, ("connection",), "m", "mobile", "nonnegative"
    ),
    "gravity": Quantity("model", _gravity, (), "m/s^2", None, "nonnegative"),
    "kp": Quantity(
        "forces", _kp, ("coordinate",), _PER_AXIS, "pose_tracking", "nonnegative"
    ),
    "kd": Quantity(
        "forces",
        _kd,
        ("coordinate",),
        "N s/m or N m s/rad per axis",
        "pose_tracking",
        "nonnegative",
    ),
    "lift_height": Quantity("forces", _lift_height, (), "m", "pose_tracking", None),
    "lift_time": Quantity("forces", _lift_time, (), "s", "pose_tracking", "positive"),
}
INERTIA_AXES = ("A", "B", "C")


@dataclasses.dataclass(frozen=True)
class OutputQuantity:
    """An output a study file may keep: its factory, whether it needs a mobile
    model, and whether it has a time axis (thresholds need none)."""

    make: Callable[[], Output]
    mobile: bool
    over_time: bool
    unit: str


OUTPUTS = {
    "peak_elastic_force": OutputQuantity(peak_elastic_force, True, False, "N"),
    "peak_force_rise": OutputQuantity(peak_elastic_force_rise, True, False, "N"),
    "max_deflection": OutputQuantity(max_deflection, True, False, "m"),
    "final_pose_error": OutputQuantity(final_pose_error, False, False, "m, rad"),
    "object_pose": OutputQuantity(object_pose, False, True, "m, rad"),
    "elastic_force": OutputQuantity(elastic_force, True, True, "N"),
    "trajectory": OutputQuantity(trajectory, False, True, "m, rad"),
}
