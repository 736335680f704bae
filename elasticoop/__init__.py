"""elasticoop: a differentiable JAX simulator of the elastic system in cooperative
manipulation (m manipulators holding one object through elastic grasps).

Importing elasticoop turns on JAX's 64-bit mode (`jax_enable_x64`): tolerances such
as `rtol=1e-8` are meaningless in float32.
"""

import typing

from ._lazy import (
    lazy_attributes as _lazy_attributes,
    lazy_names as _lazy_names,
    use_float64 as _use_float64,
)
from ._version import __version__ as __version__

_use_float64()

# Every public name is imported on first use (PEP 562), so that `import elasticoop`
# costs nothing until a name is used: the command line answers `--version` and
# `--help` without importing JAX, and a first `simulate` does not pay for scipy,
# pandas, xarray, matplotlib, pydantic or optax. The imports below are the one list
# of these names: type checkers and the documentation read them, and `__getattr__`
# resolves each name to the module its statement names.
if typing.TYPE_CHECKING:
    from . import montecarlo as montecarlo
    from ._analysis import (
        Equilibrium as Equilibrium,
        LinearModel as LinearModel,
        LoadDistribution as LoadDistribution,
        Modes as Modes,
        StateSpace as StateSpace,
        grasp_matrix as grasp_matrix,
        grasp_wrenches as grasp_wrenches,
        inverse_dynamics_series as inverse_dynamics_series,
        linearize as linearize,
        load_distribution as load_distribution,
        modes as modes,
        rest_state as rest_state,
        static_equilibrium as static_equilibrium,
        trajectory_load_distribution as trajectory_load_distribution,
    )
    from ._body import RigidBody as RigidBody, kinetic_energy as kinetic_energy
    from ._cache import enable_compilation_cache as enable_compilation_cache
    from ._config import (
        DataFileError as DataFileError,
        ScenarioError as ScenarioError,
        StudyFile as StudyFile,
        StudyFileError as StudyFileError,
        load_experiment as load_experiment,
        load_scenario as load_scenario,
        load_study as load_study,
    )
    from ._examples import default_scenario as default_scenario
    from ._forces import (
        AbstractForce as AbstractForce,
        ConstantForce as ConstantForce,
        FeedbackForce as FeedbackForce,
        PoseTracking as PoseTracking,
        SampledForce as SampledForce,
        generalized_wrench as generalized_wrench,
    )
    from ._identify import (
        AbstractTransform as AbstractTransform,
        Bounded as Bounded,
        Experiment as Experiment,
        IdentificationResult as IdentificationResult,
        Log as Log,
        MisfitCheck as MisfitCheck,
        ParameterRow as ParameterRow,
        Softplus as Softplus,
        equation_error as equation_error,
        gauss_newton_uncertainty as gauss_newton_uncertainty,
        identify as identify,
        initial_state_from_data as initial_state_from_data,
        savitzky_golay as savitzky_golay,
    )
    from ._integrate import StepwiseAdjoint as StepwiseAdjoint
    from ._io.xarray import trajectory_to_xarray as trajectory_to_xarray
    from ._lagrange import (
        accelerations as accelerations,
        constrained_accelerations as constrained_accelerations,
        damping_forces as damping_forces,
        elastic_forces as elastic_forces,
        inverse_dynamics as inverse_dynamics,
        mass_matrix as mass_matrix,
        velocity_terms as velocity_terms,
    )
    from ._models import (
        AbstractElasticModel as AbstractElasticModel,
        Connection as Connection,
        ImmobileModel as ImmobileModel,
        MobileModel as MobileModel,
        connection_dissipation as connection_dissipation,
        connection_potential as connection_potential,
        deflection as deflection,
        linearize_mobile as linearize_mobile,
    )
    from ._motion import (
        AbstractMotion as AbstractMotion,
        PrescribedMotion as PrescribedMotion,
        SplineMotion as SplineMotion,
    )
    from ._options import (
        GIMBAL_TOL as GIMBAL_TOL,
        LINK_TOL as LINK_TOL,
        SimulationOptions as SimulationOptions,
    )
    from ._plotting import (
        plot_coordinates as plot_coordinates,
        plot_elastic_wrench as plot_elastic_wrench,
        plot_energy as plot_energy,
        plot_fit as plot_fit,
        plot_loss_history as plot_loss_history,
        plot_mode_shapes as plot_mode_shapes,
        plot_morris as plot_morris,
        plot_snapshots as plot_snapshots,
        plot_sobol_convergence as plot_sobol_convergence,
        plot_sobol_heatmap as plot_sobol_heatmap,
        plot_sobol_indices as plot_sobol_indices,
        plot_study_histograms as plot_study_histograms,
        plot_study_quantiles as plot_study_quantiles,
        plot_study_sensitivity as plot_study_sensitivity,
        save_animation as save_animation,
    )
    from ._rotations import (
        RPY as RPY,
        ZXZ as ZXZ,
        AbstractRotation as AbstractRotation,
        get_rotation as get_rotation,
    )
    from ._scenario import (
        PrescribedSpec as PrescribedSpec,
        Scenario as Scenario,
    )
    from ._simulate import (
        SimulationError as SimulationError,
        simulate as simulate,
    )
    from ._status import Status as Status
    from ._trajectory import Trajectory as Trajectory
    from .montecarlo import (
        check_dgsm_bounds as check_dgsm_bounds,
        dgsm as dgsm,
        morris_effects as morris_effects,
        sensitivity_study as sensitivity_study,
        sobol_convergence as sobol_convergence,
        sobol_indices as sobol_indices,
    )


__getattr__, __dir__ = _lazy_attributes(__name__, __file__)
# `from elasticoop import *`: the public names, the same list
__all__ = sorted(_lazy_names(__file__))
