"""Plots of a trajectory and of a Monte Carlo study's results (matplotlib); every
function returns the Figure."""

from .identification import (
    plot_fit as plot_fit,
    plot_loss_history as plot_loss_history,
)
from .modes import plot_mode_shapes as plot_mode_shapes
from .montecarlo import (
    plot_study_histograms as plot_study_histograms,
    plot_study_quantiles as plot_study_quantiles,
    plot_study_sensitivity as plot_study_sensitivity,
)
from .sensitivity import (
    plot_morris as plot_morris,
    plot_sobol_convergence as plot_sobol_convergence,
    plot_sobol_heatmap as plot_sobol_heatmap,
    plot_sobol_indices as plot_sobol_indices,
)
from .time_series import (
    elastic_load_count as elastic_load_count,
    plot_coordinates as plot_coordinates,
    plot_elastic_wrench as plot_elastic_wrench,
    plot_energy as plot_energy,
)
from .view3d import plot_snapshots as plot_snapshots, save_animation as save_animation
