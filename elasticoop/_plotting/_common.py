"""Shared helpers of the plots: figures without pyplot, names, poses."""

import io

import jax
import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure as _MatplotlibFigure

from .._models import MobileModel
from .._naming import body_names

# One colour per axis/coordinate component, the same in every plot.
COMPONENT_COLOURS = ("tab:red", "tab:green", "tab:blue")


class Figure(_MatplotlibFigure):
    """A matplotlib Figure that a notebook shows as its picture (without pyplot, a
    notebook has no display rule for a Figure and shows its text form)."""

    def _repr_png_(self) -> bytes:
        buffer = io.BytesIO()
        self.savefig(buffer, format="png")
        return buffer.getvalue()


def new_figure(width: float, height: float) -> Figure:
    """A matplotlib Figure on the Agg canvas (no pyplot, no global state), shown as
    its picture in a notebook."""
    fig = Figure(figsize=(width, height), layout="constrained")
    FigureCanvasAgg(fig)
    return fig


def resolve_body_names(traj, names=None) -> tuple[str, ...]:
    return body_names(names, traj.model.n_bodies)


def angle_names(traj) -> tuple[str, str, str]:
    return tuple(traj.model.rotation.angle_names)


def check_single(traj) -> None:
    if np.ndim(traj.ts) != 1:
        raise ValueError(
            f"plots need a single trajectory (ts of shape (times,)), got ts of shape "
            f"{np.shape(traj.ts)}; index the batch first"
        )


def rotation_matrices(traj) -> np.ndarray:
    """$R$ (body -> world) of every body at every time, shape (times, bodies, 3, 3)."""
    rot = traj.model.rotation
    return np.asarray(jax.vmap(jax.vmap(rot.matrix))(traj.y[..., 3:]))


def links(traj) -> list[tuple[int, ...]]:
    """Pairs of bodies to draw as links: the connections of a `MobileModel`, the
    bodies coupled by a non-zero block of K for an `ImmobileModel`."""
    model = traj.model
    if isinstance(model, MobileModel):
        return [tuple(int(v) for v in p) for p in np.asarray(model.pairs)]
    K = np.asarray(model.K)
    n = model.n_bodies
    return [
        (i, j)
        for i in range(n)
        for j in range(i + 1, n)
        if np.any(K[6 * i : 6 * i + 6, 6 * j : 6 * j + 6] != 0)
    ]
