"""Plot of mode shapes."""

import numpy as np

from .._analysis.modes import Modes
from ._common import new_figure


def plot_mode_shapes(modes: Modes, count: int = 4):
    """Bar charts of the first `count` mode shapes (mass-normalized, scaled to a
    largest entry of 1), one panel per mode, titled with its frequency and damping
    ratio. Returns the matplotlib `Figure`."""
    count = min(count, len(modes.frequencies))
    if count < 1:
        raise ValueError(f"count must be at least 1, got {count}")
    fig = new_figure(max(6.0, 0.35 * len(modes.names)), 1.9 * count + 0.6)
    axes = fig.subplots(count, 1, sharex=True, squeeze=False)
    x = np.arange(len(modes.names))
    for k, ax in enumerate(axes[:, 0]):
        shape = modes.shapes[:, k]
        shape = shape / np.max(np.abs(shape))
        ax.bar(x, shape, color=np.where(shape >= 0, "tab:blue", "tab:orange"))
        ax.axhline(0.0, color="black", linewidth=0.6)
        zeta = modes.damping_ratios[k]
        label = "" if np.isnan(zeta) else f", zeta = {zeta:.3g}"
        ax.set_title(
            f"mode {k + 1}: f = {modes.frequencies_hz[k]:.3g} Hz{label}", fontsize=10
        )
        ax.set_ylabel("relative amplitude")
        ax.set_ylim(-1.15, 1.15)
    axes[-1, 0].set_xticks(x, modes.names, rotation=60, ha="right", fontsize=8)
    axes[-1, 0].set_xlabel("free coordinate")
    return fig
