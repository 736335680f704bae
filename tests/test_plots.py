"""Plot functions: checked on the figure objects (axes, labels, legends, data)."""

import jax.numpy as jnp
import numpy as np
import pytest
from helpers import two_body_run
from matplotlib.figure import Figure
from PIL import Image

from elasticoop._plotting import (
    plot_coordinates,
    plot_elastic_wrench,
    plot_energy,
    plot_snapshots,
    plot_study_histograms,
    plot_study_quantiles,
    save_animation,
)
from elasticoop._plotting.view3d import inertia_box

TS = jnp.linspace(0.0, 0.2, 11)
# The residual is summed in another order than Trajectory.energy_residual: energies
# of ~20 J agree to a few float64 roundings.
ROUNDING = 1e-12


@pytest.fixture(scope="module")
def traj():
    return two_body_run()[0]


@pytest.fixture(scope="module")
def immobile_traj():
    return two_body_run()[1]


def legend_labels(ax):
    legend = ax.get_legend()
    return [t.get_text() for t in legend.get_texts()] if legend else []


def test_coordinates_figure(traj):
    fig = plot_coordinates(traj, body_names=["obj", "grip"])
    assert isinstance(fig, Figure)
    axes = fig.get_axes()
    assert len(axes) == 4  # positions and angles for each of 2 bodies
    assert [ax.get_title() for ax in axes[:2]] == ["obj", "grip"]
    assert axes[0].get_ylabel() == "change of position [m]"
    assert axes[2].get_ylabel() == "change of Euler angle [deg]"
    assert all(ax.get_xlabel() == "time [s]" for ax in axes[2:])
    assert legend_labels(axes[1]) == ["x", "y", "z"]
    assert legend_labels(axes[3]) == ["psi", "theta", "phi"]
    # the z line of the grasp is its displacement from t0
    z_line = axes[1].get_lines()[2]
    np.testing.assert_allclose(z_line.get_ydata(), traj.y[:, 1, 2] - traj.y[0, 1, 2])
    absolute = plot_coordinates(traj, relative=False).get_axes()
    assert absolute[0].get_ylabel() == "position [m]"
    assert absolute[0].get_title() == "object"


def test_elastic_wrench_figure(traj, immobile_traj):
    fig = plot_elastic_wrench(traj, connection_names=["grasp"])
    top, bottom = fig.get_axes()
    assert top.get_title().startswith("grasp")
    assert top.get_ylabel() == "force [N]"
    assert bottom.get_ylabel() == "generalized torque [N m]"
    assert bottom.get_xlabel() == "time [s]"
    assert legend_labels(top) == ["x", "y", "z", "|F|"]
    assert legend_labels(bottom) == ["Q_psi", "Q_theta", "Q_phi"]
    magnitude = top.get_lines()[3].get_ydata()
    np.testing.assert_allclose(
        magnitude, np.linalg.norm(traj.elastic_wrench()[:, 0, :3], axis=-1)
    )
    fig = plot_elastic_wrench(immobile_traj)
    assert fig.get_axes()[0].get_title().startswith("contact1")
    assert fig._suptitle.get_text() == "Elastic force on each contact body"


def test_energy_figure(traj):
    fig = plot_energy(traj)
    top, bottom = fig.get_axes()
    assert top.get_ylabel() == "energy [J]" and bottom.get_ylabel() == "residual [J]"
    assert bottom.get_xlabel() == "time [s]"
    assert legend_labels(top) == [
        "kinetic T",
        "elastic Pi",
        "gravity m g z (change)",
        "work of forces W_F",
        "dissipated E_diss",
        "total E (change)",
    ]
    total = top.get_lines()[5].get_ydata()
    energy = np.asarray(traj.total_energy())
    np.testing.assert_allclose(total, energy - energy[0], rtol=0, atol=ROUNDING)
    np.testing.assert_allclose(
        bottom.get_lines()[0].get_ydata(),
        traj.energy_residual(),
        rtol=0,
        atol=ROUNDING,
    )


def test_snapshots_figure(traj, immobile_traj):
    fig = plot_snapshots(traj, times=[0.0, 0.1, 0.2], body_names=["obj", "grip"])
    axes = fig.get_axes()
    assert len(axes) == 3 and all(ax.name == "3d" for ax in axes)
    assert [ax.get_title() for ax in axes] == ["t = 0 s", "t = 0.1 s", "t = 0.2 s"]
    assert (axes[0].get_xlabel(), axes[0].get_zlabel()) == ("x [m]", "z [m]")
    # at the start: one link line, then a triad (3 lines) per body; later panels
    # first draw the object's path since the start
    assert len(axes[0].get_lines()) == 1 + 3 * 2
    path, link = axes[-1].get_lines()[:2]
    assert len(axes[-1].get_lines()) == 1 + 1 + 3 * 2
    np.testing.assert_allclose(link.get_data_3d()[2], traj.y[-1, :, 2])
    np.testing.assert_allclose(path.get_data_3d()[2], traj.y[:, 0, 2])
    # a box per body, and the boxes at the start drawn faintly after the start
    assert len(axes[0].collections) == 2 + 2  # the boxes and the two centre dots
    assert len(axes[-1].collections) == 2 + 2 + 2
    labels = [t.get_text() for t in fig.legends[0].get_texts()]
    assert labels == [
        "body x axis",
        "body y axis",
        "body z axis",
        "link",
        "at the start",
        "object's path",
    ]
    assert len(plot_snapshots(immobile_traj).get_axes()) == 4
    with pytest.raises(ValueError, match="outside"):
        plot_snapshots(traj, times=[5.0])
    with pytest.raises(ValueError, match="sizes"):
        plot_snapshots(traj, sizes=[[0.1, 0.1, 0.1]])


def test_snapshots_frame_the_bodies_at_one_scale(traj):
    """The axes hold every body's box over the run, at the same scale on the three
    axes (the boxes keep their shapes), and fit the motion: no axis is longer than
    the scene needs (the longest spans the boxes' extent plus a margin)."""
    sizes = np.array([[0.4, 0.1, 0.05], [0.02, 0.02, 0.02]])
    (ax,) = plot_snapshots(traj, times=[0.2], sizes=sizes).get_axes()
    limits = np.array([ax.get_xlim(), ax.get_ylim(), ax.get_zlim()])
    spans = limits[:, 1] - limits[:, 0]
    np.testing.assert_allclose(
        ax.get_box_aspect() / spans,
        1 / spans.max() * 1.0 * (ax.get_box_aspect().max()),
        rtol=1e-9,
    )
    r = np.asarray(traj.y[:, :, :3])
    reach = np.linalg.norm(sizes, axis=1).max() / 2
    assert np.all(limits[:, 0] <= r.min((0, 1)) - 0.0) and np.all(
        limits[:, 1] >= r.max((0, 1))
    )
    extent = (r.max((0, 1)) - r.min((0, 1))).max() + 2 * reach
    assert spans.max() < 1.5 * extent


def test_inertia_box_is_the_uniform_box():
    # a uniform box of mass 12 kg and sides 1, 2, 3 m: A = m (b^2 + c^2) / 12 ...
    sides = inertia_box([12.0], [[13.0, 10.0, 5.0]])
    np.testing.assert_allclose(sides, [[1.0, 2.0, 3.0]])
    # a flat body at the triangle inequality's edge: a plate of no thickness
    np.testing.assert_allclose(inertia_box(1.0, [1.0, 2.0, 3.0])[2], 0.0, atol=1e-7)


def _study(moving_y: bool):
    """A made-up study's results: 6 samples, 5 times, 2 bodies, x y z; only z
    varies (and y of body 1 when `moving_y`)."""
    import xarray as xr

    rng = np.random.default_rng(0)
    pose = np.zeros((6, 5, 2, 3))
    pose[..., 2] = rng.normal(size=(6, 5, 2))
    if moving_y:
        pose[:, :, 1, 1] = rng.normal(size=(6, 5))
    peak = np.stack([rng.normal(size=6), np.full(6, 3.0)], axis=1)
    return xr.Dataset(
        {
            "pose": (("sample", "time", "body", "coordinate"), pose),
            "peak": (("sample", "connection"), peak),
            "status": (("sample",), np.zeros(6, int)),
        },
        coords={
            "time": np.linspace(0, 1, 5),
            "body": ["beam", "left"],
            "coordinate": ["x", "y", "z"],
            "connection": ["a", "b"],
        },
    )


def test_study_plots_leave_out_what_never_moves():
    fig = plot_study_quantiles(_study(moving_y=True), "pose", "m")
    titles = [ax.get_title() for ax in fig.get_axes() if ax.get_visible()]
    assert titles == ["beam, z", "left, y", "left, z"]
    assert "not shown: beam, x, beam, y, left, x" in fig._suptitle.get_text()
    fig = plot_study_histograms(_study(moving_y=False), "peak", thresholds=[1.0])
    assert [ax.get_title() for ax in fig.get_axes() if ax.get_visible()] == ["a"]
    assert "not shown: b" in fig._suptitle.get_text()


def test_animation_gif(traj, tmp_path):
    path = save_animation(traj, tmp_path / "motion.gif", max_frames=3)
    with Image.open(path) as gif:
        assert gif.n_frames == 3
    with pytest.raises(ValueError, match=".gif or .mp4"):
        save_animation(traj, tmp_path / "motion.avi")


def test_a_notebook_shows_a_figure_as_its_picture(traj):
    """Old: without pyplot imported, a notebook showed the library's figures as
    `<Figure size 1440x1440 with 7 Axes>`: a Figure has no picture of its own for
    IPython's display (`_repr_png_`, which IPython asks a value for)."""
    import io

    fig = plot_coordinates(traj)
    png = fig._repr_png_()
    assert png.startswith(b"\x89PNG\r\n\x1a\n")
    width, height = Image.open(io.BytesIO(png)).size
    dpi = fig.get_dpi()
    assert (width, height) == tuple(round(v * dpi) for v in fig.get_size_inches())
