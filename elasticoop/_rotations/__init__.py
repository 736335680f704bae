"""Euler-angle sequences: per sequence only $R$ and $L_\\omega$ are written."""

from .base import AbstractRotation as AbstractRotation
from .rpy import RPY as RPY
from .zxz import ZXZ as ZXZ

CONVENTIONS: dict[str, AbstractRotation] = {"zxz": ZXZ(), "rpy": RPY()}


def get_rotation(convention: str) -> AbstractRotation:
    """The rotation object for a convention name (`"zxz"` or `"rpy"`)."""
    try:
        return CONVENTIONS[convention]
    except (KeyError, TypeError):
        raise ValueError(
            f"convention must be one of {sorted(CONVENTIONS)}, got {convention!r}"
        ) from None
