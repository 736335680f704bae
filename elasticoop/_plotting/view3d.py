"""3-D views of the bodies: an axes triad at each body's pose, links as lines;
still snapshots at chosen instants and an animation export."""

from typing import TYPE_CHECKING

import numpy as np
from matplotlib.lines import Line2D
from matplotlib.ticker import MaxNLocator

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


class _Scene:
    """Positions, rotations and links of a trajectory, with fixed axis limits."""

    def __init__(self, traj, body_names=None):
        check_single(traj)
        self.names = resolve_body_names(traj, body_names)
        self.ts = np.asarray(traj.ts)
        self.r = np.asarray(traj.y[..., :3])
        self.R = rotation_matrices(traj)
        self.links = links(traj)
        finite = self.r[np.all(np.isfinite(self.r), axis=(1, 2))]
        lo, hi = finite.reshape(-1, 3).min(0), finite.reshape(-1, 3).max(0)
        span = max(float(np.max(hi - lo)), 1e-3)
        self.triad = 0.18 * span
        half = 0.5 * span + 1.5 * self.triad
        self.centre = 0.5 * (lo + hi)
        self.half = half

    def index(self, t: float) -> int:
        return int(np.argmin(np.abs(self.ts - t)))

    def draw(self, ax, k: int | np.integer, labels: bool = True):
        r, R = self.r[k], self.R[k]
        for i, j in self.links:
            ax.plot(*np.stack([r[i], r[j]]).T, color="0.45", linewidth=2.5)
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
            lim = (self.centre[d] - self.half, self.centre[d] + self.half)
            getattr(ax, f"set_{name}lim")(lim)
        ax.set_box_aspect((1, 1, 1), zoom=0.88)
        ax.view_init(elev=VIEW_ELEVATION, azim=VIEW_AZIMUTH)
        for axis, name in zip((ax.xaxis, ax.yaxis, ax.zaxis), "xyz"):
            axis.set_major_locator(MaxNLocator(4))
            axis.set_label_text(f"{name} [m]")
        ax.tick_params(labelsize=7, pad=1)
        ax.set_title(f"t = {self.ts[k]:.3g} s")


def _legend_handles():
    handles = [
        Line2D([], [], color=colour, linewidth=2, label=f"body {axis} axis")
        for axis, colour in zip("xyz", COMPONENT_COLOURS)
    ]
    handles.append(Line2D([], [], color="0.45", linewidth=2.5, label="link"))
    return handles


def plot_snapshots(traj, times=None, body_names=None, n_snapshots: int = 4):
    """3-D views of the bodies at chosen instants, one panel per instant: an axes
    triad (x red, y green, z blue) at each body's pose and a line for each link
    (the connections of a `MobileModel`, the coupled bodies of an `ImmobileModel`).

    **Arguments:**

    - `traj`: a `Trajectory`.
    - `times`: instants [s] (the nearest output times are shown); default
      `n_snapshots` evenly spaced over the run.
    - `body_names`: labels of the bodies.

    **Returns:** the `matplotlib.figure.Figure`.
    """
    scene = _Scene(traj, body_names)
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
    fig = new_figure(4.2 * cols, 4.0 * rows + 0.6)
    for p, t in enumerate(times):
        ax = fig.add_subplot(rows, cols, p + 1, projection="3d")
        scene.draw(ax, scene.index(t))
    fig.legend(handles=_legend_handles(), loc="outside lower center", ncols=4)
    fig.suptitle("Bodies and links (axes triads at the body poses)")
    return fig


def save_animation(
    traj, path, body_names=None, fps: int = 20, max_frames: int = 80
) -> "pathlib.Path":
    """Write a 3-D animation of the bodies (as in `plot_snapshots`) to `path`.

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
    scene = _Scene(traj, body_names)
    finite = np.nonzero(np.all(np.isfinite(scene.r), axis=(1, 2)))[0]
    frames = finite[np.unique(np.linspace(0, finite.size - 1, max_frames).astype(int))]
    fig = new_figure(5.5, 5.0)
    ax = fig.add_subplot(projection="3d")
    fig.legend(
        handles=_legend_handles(), loc="outside lower center", ncols=4, fontsize="small"
    )

    def update(k):
        ax.clear()
        scene.draw(ax, k)
        return []

    anim = animation.FuncAnimation(fig, update, frames=list(frames), blit=False)
    path.parent.mkdir(parents=True, exist_ok=True)
    anim.save(path, writer=writer)
    return path
