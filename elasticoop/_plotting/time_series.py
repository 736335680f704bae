"""Quantities over time: coordinates per body, elastic wrench per connection, and
the energy balance."""

import numpy as np

from .._models import MobileModel
from .._naming import connection_names as connection_names_of
from ._common import (
    COMPONENT_COLOURS,
    angle_names,
    check_single,
    new_figure,
    resolve_body_names,
)


def _grid(fig, rows, cols):
    axes = fig.subplots(rows, cols, sharex=True, squeeze=False)
    return axes


def plot_coordinates(traj, body_names=None, relative: bool = True):
    """Coordinates over time, one column per body: positions (top, [m]) and Euler
    angles (bottom, [deg]).

    **Arguments:**

    - `traj`: a `Trajectory`.
    - `body_names`: names for the column titles (default object, contact1, ...).
    - `relative`: plot the change from $t_0$ (default; small motions stay visible)
      instead of the absolute values.

    **Returns:** the `matplotlib.figure.Figure`.
    """
    check_single(traj)
    names = resolve_body_names(traj, body_names)
    n = len(names)
    t = np.asarray(traj.ts)
    y = np.asarray(traj.y)
    if relative:
        y = y - y[:1]
    fig = new_figure(max(6.0, 3.4 * n), 5.2)
    axes = _grid(fig, 2, n)
    angles = angle_names(traj)
    prefix = "change of " if relative else ""
    for b in range(n):
        top, bottom = axes[0, b], axes[1, b]
        for c, (label, colour) in enumerate(zip(("x", "y", "z"), COMPONENT_COLOURS)):
            top.plot(t, y[:, b, c], color=colour, label=label)
            bottom.plot(t, np.degrees(y[:, b, 3 + c]), color=colour, label=angles[c])
        top.set_title(names[b])
        bottom.set_xlabel("time [s]")
        for ax in (top, bottom):
            ax.grid(True, alpha=0.3)
            ax.ticklabel_format(axis="y", style="sci", scilimits=(-3, 4))
    axes[0, 0].set_ylabel(f"{prefix}position [m]")
    axes[1, 0].set_ylabel(f"{prefix}Euler angle [deg]")
    for ax in axes[:, -1]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small")
    fig.suptitle(
        "Coordinates over time"
        + (" (change from the initial state)" if relative else "")
    )
    return fig


def elastic_load_count(traj) -> int:
    """The number of columns of `plot_elastic_wrench`: the connections of a
    `MobileModel`, the contact bodies of an `ImmobileModel` (zero for a body on
    its own, which has nothing to plot)."""
    model = traj.model
    if isinstance(model, MobileModel):
        return int(np.shape(model.pairs)[0])
    return model.n_bodies - 1


def plot_elastic_wrench(traj, connection_names=None, body_names=None):
    """Elastic wrench over time, one column per connection (`MobileModel`:
    $-\\partial\\Pi_{ij}/\\partial Y_i$ on the connection's first body) or per contact
    body (`ImmobileModel`: $-\\partial\\Pi/\\partial Y_i$): force components and
    magnitude [N] (top), generalized torques [N m] (bottom).

    **Returns:** the `matplotlib.figure.Figure`.
    """
    check_single(traj)
    if elastic_load_count(traj) == 0:
        raise ValueError("the model has no connections or contact bodies to plot")
    names = resolve_body_names(traj, body_names)
    t = np.asarray(traj.ts)
    pairs, wrench = traj.grasp_loads()
    wrench = np.asarray(wrench)
    if isinstance(traj.model, MobileModel):
        labels = connection_names_of(connection_names, pairs, names)
        titles = [f"{label}\n(on {names[i]})" for label, (i, j) in zip(labels, pairs)]
        what = "Elastic wrench per connection"
    else:
        titles = [f"{name}\n(-dPi/dY)" for name in names[1:]]
        what = "Elastic force on each contact body"
    count = wrench.shape[1]
    fig = new_figure(max(6.0, 3.6 * count), 5.2)
    axes = _grid(fig, 2, count)
    angles = angle_names(traj)
    for k in range(count):
        top, bottom = axes[0, k], axes[1, k]
        for c, colour in enumerate(COMPONENT_COLOURS):
            top.plot(t, wrench[:, k, c], color=colour, label="xyz"[c])
            bottom.plot(t, wrench[:, k, 3 + c], color=colour, label=f"Q_{angles[c]}")
        top.plot(
            t,
            np.linalg.norm(wrench[:, k, :3], axis=-1),
            color="black",
            linestyle="--",
            label="|F|",
        )
        top.set_title(titles[k])
        bottom.set_xlabel("time [s]")
        for ax in (top, bottom):
            ax.grid(True, alpha=0.3)
    axes[0, 0].set_ylabel("force [N]")
    axes[1, 0].set_ylabel("generalized torque [N m]")
    for ax in axes[:, -1]:
        ax.legend(loc="upper left", bbox_to_anchor=(1.02, 1.0), fontsize="small")
    fig.suptitle(what)
    return fig


def plot_energy(traj):
    """Energy balance over time: kinetic $T$, elastic $\\Pi$, change of gravity
    potential, work of the applied forces $W_F$, dissipated energy $E_{diss}$ and
    the change of the total $E$ (top, [J]); the residual
    $E - E(t_0) - W_F + E_{diss}$ (bottom, [J]), zero up to the solver's error.

    **Returns:** the `matplotlib.figure.Figure`.
    """
    check_single(traj)
    t = np.asarray(traj.ts)
    kinetic = np.asarray(traj.kinetic_energy())
    elastic = np.asarray(traj.elastic_energy())
    gravity = np.asarray(traj.gravity_energy())
    work = np.asarray(traj.work)
    dissipated = np.asarray(traj.dissipated)
    total = kinetic + elastic + gravity
    fig = new_figure(7.5, 6.0)
    top, bottom = fig.subplots(2, 1, sharex=True, gridspec_kw={"height_ratios": [3, 1]})
    top.plot(t, kinetic, label="kinetic T")
    top.plot(t, elastic, label="elastic Pi")
    top.plot(t, gravity - gravity[0], label="gravity m g z (change)")
    top.plot(t, work, label="work of forces W_F", linestyle="--")
    top.plot(t, dissipated, label="dissipated E_diss", linestyle="--")
    top.plot(t, total - total[0], label="total E (change)", color="black", linewidth=2)
    top.set_ylabel("energy [J]")
    top.legend(loc="best", fontsize="small")
    top.grid(True, alpha=0.3)
    top.set_title("Energy balance: change of E = W_F - E_diss")
    residual = total - total[0] - work + dissipated
    bottom.plot(t, residual, color="tab:red", label="E - E(t0) - W_F + E_diss")
    bottom.set_ylabel("residual [J]")
    bottom.set_xlabel("time [s]")
    bottom.legend(loc="best", fontsize="small")
    bottom.grid(True, alpha=0.3)
    bottom.ticklabel_format(axis="y", style="sci", scilimits=(-2, 2))
    return fig
