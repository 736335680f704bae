"""Plots of a fit: measured against fitted motion, and the loss history."""

import numpy as np

from .._naming import (
    TRANSLATION_NAMES,
    body_names as checked_body_names,
    coordinate_names,
)
from ._common import new_figure


def plot_fit(
    ts,
    measured,
    fitted,
    body_names=None,
    convention: str = "zxz",
    title: str = "",
):
    """Measured samples (dots) against the fitted model's motion (line), one panel
    per coordinate: a row per body, a column per coordinate (positions in m, Euler
    angles in degrees).

    **Arguments:**

    - `ts`: sample times [s], `(times,)`.
    - `measured`: measured $Y$, `(times, bodies, 6)` (NaN: missing, not drawn).
    - `fitted`: $Y$ simulated with the fitted parameters at `ts`, same shape.
    - `body_names`: body names (default `object, contact1, ...`).
    - `convention`: the Euler convention (names the angle columns).
    - `title`: the figure's title.

    **Returns:** a matplotlib `Figure`.
    """
    ts = np.asarray(ts, dtype=float)
    measured, fitted = np.asarray(measured), np.asarray(fitted)
    n_bodies = measured.shape[1]
    names = checked_body_names(body_names, n_bodies)
    coords = coordinate_names(convention)
    fig = new_figure(2.6 * 6, 1.9 * n_bodies + 0.6)
    axes = fig.subplots(n_bodies, 6, sharex=True, squeeze=False)
    for i in range(n_bodies):
        for c in range(6):
            ax = axes[i, c]
            scale = 1.0 if coords[c] in TRANSLATION_NAMES else 180.0 / np.pi
            unit = "m" if scale == 1.0 else "deg"
            ax.plot(ts, measured[:, i, c] * scale, ".", ms=2.5, color="0.45")
            ax.plot(ts, fitted[:, i, c] * scale, "-", lw=1.2, color="tab:blue")
            ax.set_title(f"{names[i]}.{coords[c]} [{unit}]", fontsize=8)
            ax.tick_params(labelsize=7)
            if i == n_bodies - 1:
                ax.set_xlabel("t [s]", fontsize=8)
    axes[0, 0].legend(["measured", "fitted"], fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    return fig


def plot_loss_history(
    loss_history, title: str = "loss history", noise_floor: float | None = None
):
    """The loss $\\tfrac12\\sum r^2$ after each accepted iteration of a fit
    (`IdentificationResult.loss_history`), on a log scale, with the noise floor
    (`IdentificationResult.misfit.noise_floor`, the loss the declared noise alone
    explains, $\\tfrac12 (N - n_p)$) as a dashed line where it is given: a fit
    that explains its data ends on it.

    **Returns:** a matplotlib `Figure`.
    """
    loss = np.asarray(loss_history, dtype=float)
    fig = new_figure(5.0, 3.2)
    ax = fig.subplots()
    ax.semilogy(np.arange(len(loss)), loss, "o-", ms=3, label="loss")
    if noise_floor is not None and np.isfinite(noise_floor) and noise_floor > 0:
        ax.axhline(noise_floor, color="0.4", ls="--", lw=1, label="noise floor")
        ax.legend(loc="upper right", fontsize=8)
    ax.set_xlabel("iteration")
    ax.set_ylabel("loss")
    ax.set_title(title)
    ax.grid(True, which="both", alpha=0.3)
    return fig
