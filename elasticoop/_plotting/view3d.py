"""3-D views of the bodies: each body a box at its pose, with an axes triad, links
as lines, the pose at the start drawn faintly and the object's path; still
snapshots at chosen instants and an animation export."""

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.artist import Artist
from matplotlib.lines import Line2D
from matplotlib.patches import Patch
from matplotlib.ticker import MaxNLocator
from mpl_toolkits.mplot3d.art3d import Poly3DCollection

from ._common import (
    COMPONENT_COLOURS,
    check_single,
    links,
    new_figure,
    resolve_body_names,
    rotation_matrices,
)

if TYPE_CHECKING:
    import pathlib

# Camera: a little above the horizon and mostly along -y, so lifts along z and
# layouts along x read at a glance.
VIEW_ELEVATION = 18.0
VIEW_AZIMUTH = -68.0
# Each axis spans at least this share of the longest one, so that a flat scene
# keeps some depth; the scale is the same on the three axes (true shapes).
MIN_AXIS_SHARE = 0.3
BODY_COLOURS = ("tab:orange", "tab:purple", "tab:cyan", "tab:olive", "tab:pink")
# The eight corners of a unit box centred at the origin, and its six faces.
_CORNERS = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
)
_FACES = (
    (0, 1, 3, 2),
    (4, 5, 7, 6),
    (0, 1, 5, 4),
    (2, 3, 7, 6),
    (0, 2, 6, 4),
    (1, 3, 7, 5),
)


def inertia_box(mass, inertia) -> np.ndarray:
    """Sides $(a, b, c)$ [m] of the uniform box with the body's mass and principal
    moments: $A = m(b^2 + c^2)/12$ and so on, so $a^2 = 6(B + C - A)/m$ (the
    triangle inequalities keep these non-negative). Shape `(bodies, 3)`."""
    m = np.asarray(mass, dtype=float)[..., None]
    A, B, C = np.moveaxis(np.asarray(inertia, dtype=float), -1, 0)
    squares = 6.0 * np.stack([B + C - A, A + C - B, A + B - C], axis=-1) / m
    return np.sqrt(np.maximum(squares, 0.0))


def _box_sizes(traj, sizes) -> np.ndarray:
    n = traj.model.n_bodies
    if sizes is None:
        bodies = traj.model.bodies
        return inertia_box(bodies.mass, bodies.inertia)
    sizes = np.asarray(sizes, dtype=float)
    if sizes.shape != (n, 3) or not np.all(np.isfinite(sizes)) or np.any(sizes < 0):
        raise ValueError(
            f"sizes must be the sides [m] of a box per body, non-negative, of shape "
            f"({n}, 3); got {sizes.tolist()}"
        )
    return sizes


class _Scene:
    """Positions, rotations, box corners and links of a trajectory, with fixed axis
    limits that hold every body's box over the whole run."""

    def __init__(self, traj, body_names=None, sizes=None):
        check_single(traj)
        self.names = resolve_body_names(traj, body_names)
        self.ts = np.asarray(traj.ts)
        self.r = np.asarray(traj.y[..., :3])
        self.R = rotation_matrices(traj)
        self.links = links(traj)
        self.sizes = _box_sizes(traj, sizes)
        # corners[k, b, c] = r + R (sides * unit corner), (times, bodies, 8, 3)
        local = _CORNERS[None, :, :] * self.sizes[:, None, :]
        self.corners = self.r[:, :, None, :] + np.einsum(
            "kbij,bcj->kbci", self.R, local
        )
        self.finite = np.nonzero(np.all(np.isfinite(self.corners), axis=(1, 2, 3)))[0]
        points = self.corners[self.finite].reshape(-1, 3)
        if points.size == 0:
            points = np.zeros((1, 3))
        lo, hi = points.min(0), points.max(0)
        longest = max(float(np.max(hi - lo)), 1e-3)
        self.triad = 0.15 * longest
        half = np.maximum(0.5 * (hi - lo), 0.5 * MIN_AXIS_SHARE * longest)
        half += 0.08 * longest + 0.5 * self.triad * np.array([0.0, 0.0, 1.0])
        self.centre = 0.5 * (lo + hi)
        self.half = half

    @property
    def height_share(self) -> float:
        """A panel's height over its width that fits the view of the scene."""
        return 0.5 + 0.5 * float(self.half[2] / self.half.max())

    def index(self, t: float) -> int:
        return int(np.argmin(np.abs(self.ts - t)))

    def _boxes(self, ax, k, faint: bool) -> None:
        for b in range(self.r.shape[1]):
            corners = self.corners[k, b]
            if not np.all(np.isfinite(corners)) or not np.any(self.sizes[b] > 0):
                continue
            faces = [corners[list(face)] for face in _FACES]
            if faint:
                box = Poly3DCollection(
                    faces, facecolors="none", edgecolors="0.6", linewidths=0.6
                )
                box.set_linestyle(":")
            else:
                box = Poly3DCollection(
                    faces,
                    facecolors=BODY_COLOURS[b % len(BODY_COLOURS)],
                    edgecolors="0.25",
                    linewidths=0.5,
                    alpha=0.35,
                )
            ax.add_collection3d(box)

    def draw(self, ax, k: int | np.integer, labels: bool = True):
        r, R = self.r[k], self.R[k]
        start = self.finite[0] if self.finite.size else 0
        if k != start:  # where the bodies started, and the object's path since
            self._boxes(ax, start, faint=True)
            path = self.r[start : k + 1, 0]
            ax.plot(*path.T, color="0.3", linestyle="--", linewidth=1)
        for i, j in self.links:
            ax.plot(*np.stack([r[i], r[j]]).T, color="0.45", linewidth=2.5)
        self._boxes(ax, k, faint=False)
        for b in range(r.shape[0]):
            if not np.all(np.isfinite(r[b])):
                continue
            for c, colour in enumerate(COMPONENT_COLOURS):
                end = r[b] + self.triad * R[b][:, c]
                ax.plot(*np.stack([r[b], end]).T, color=colour, linewidth=2)
            ax.scatter(*r[b], color="black", s=12 if b else 30, depthshade=False)
            if labels:
                ax.text(*(r[b] + 0.35 * self.triad), self.names[b], fontsize=8)
        for d, name in enumerate("xyz"):
            lim = (self.centre[d] - self.half[d], self.centre[d] + self.half[d])
            getattr(ax, f"set_{name}lim")(lim)
        ax.set_box_aspect(tuple(self.half / self.half.max()), zoom=0.95)
        ax.view_init(elev=VIEW_ELEVATION, azim=VIEW_AZIMUTH)
        for axis, name in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz"):
            axis.set_major_locator(MaxNLocator(4))
            axis.set_label_text(f"{name} [m]")
        ax.tick_params(labelsize=7, pad=1)
        ax.set_title(f"t = {self.ts[k]:.3g} s")


def _legend_handles() -> list[Artist]:
    handles: list[Artist] = [
        Line2D([], [], color=colour, linewidth=2, label=f"body {axis} axis")
        for axis, colour in zip("xyz", COMPONENT_COLOURS)
    ]
    handles.append(Line2D([], [], color="0.45", linewidth=2.5, label="link"))
    handles.append(
        Patch(facecolor="none", edgecolor="0.6", linestyle=":", label="at the start")
    )
    handles.append(
        Line2D([], [], color="0.3", linestyle="--", linewidth=1, label="object's path")
    )
    return handles


def plot_snapshots(traj, times=None, body_names=None, n_snapshots: int = 4, sizes=None):
    """3-D views of the bodies at chosen instants, one panel per instant: each body
    a box at its pose with an axes triad (x red, y green, z blue), a line for each
    link (the connections of a `MobileModel`, the coupled bodies of an
    `ImmobileModel`), and, from the second instant on, the boxes at the start
    (dotted) and the object's path since (dashed). The three axes share one scale
    and are fitted to the bodies' motion, so that a lift shows.

    **Arguments:**

    - `traj`: a `Trajectory`.
    - `times`: instants [s] (the nearest output times are shown); default
      `n_snapshots` evenly spaced over the run.
    - `body_names`: labels of the bodies.
    - `sizes`: the sides [m] of each body's box along its x, y, z axes, shape
      `(bodies, 3)`; default the uniform box of the body's mass and moments of
      inertia (`inertia_box`).

    **Returns:** the `matplotlib.figure.Figure`.
    """
    scene = _Scene(traj, body_names, sizes)
    if times is None:
        times = np.linspace(scene.ts[0], scene.ts[-1], n_snapshots)
    times = np.atleast_1d(np.asarray(times, dtype=float))
    if times.size == 0:
        raise ValueError("times must hold at least one instant")
    outside = times[(times < scene.ts[0]) | (times > scene.ts[-1])]
    if outside.size:
        raise ValueError(
            f"times {outside.tolist()} lie outside the trajectory's "
            f"[{scene.ts[0]}, {scene.ts[-1]}] s"
        )
    cols = 2 if times.size == 4 else min(times.size, 3)
    rows = -(-times.size // cols)
    fig = new_figure(4.2 * cols, 4.2 * scene.height_share * rows + 0.9)
    for p, t in enumerate(times):
        ax = fig.add_subplot(rows, cols, p + 1, projection="3d")
        scene.draw(ax, scene.index(t))
    fig.legend(handles=_legend_handles(), loc="outside lower center", ncols=3)
    fig.suptitle("Bodies (boxes with their axes) and links")
    return fig


def save_animation(
    traj, path, body_names=None, fps: int = 20, max_frames: int = 80, sizes=None
) -> "pathlib.Path":
    """Write a 3-D animation of the bodies (as in `plot_snapshots`, `sizes`
    included) to `path`.

    `.gif` is written with matplotlib's `PillowWriter`; `.mp4` needs ffmpeg
    (`ValueError` otherwise; use `.gif`). At most `max_frames` evenly spaced
    output times are drawn.

    **Returns:** the path written.
    """
    import pathlib

    from matplotlib import animation

    path = pathlib.Path(path)
    suffix = path.suffix.lower()
    writer: animation.AbstractMovieWriter
    if suffix == ".gif":
        writer = animation.PillowWriter(fps=fps)
    elif suffix == ".mp4":
        if not animation.writers.is_available("ffmpeg"):
            raise ValueError("writing .mp4 needs ffmpeg, which was not found; use .gif")
        writer = animation.FFMpegWriter(fps=fps)
    else:
        raise ValueError(f"animation path must end in .gif or .mp4, got {path.name!r}")
    scene = _Scene(traj, body_names, sizes)
    finite = scene.finite
    frames = finite[np.unique(np.linspace(0, finite.size - 1, max_frames).astype(int))]
    fig = new_figure(6.0, 6.0 * scene.height_share + 0.8)
    ax = fig.add_subplot(projection="3d")
    fig.legend(
        handles=_legend_handles(), loc="outside lower center", ncols=3, fontsize="small"
    )

    def update(k):
        ax.clear()
        scene.draw(ax, k)
        return []

    anim = animation.FuncAnimation(fig, update, frames=list(frames), blit=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    anim.save(path, writer=writer)
    return path
