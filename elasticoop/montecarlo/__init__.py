"""Monte Carlo studies: sampling, batched execution, statistics, sensitivities."""

from ._sensitivity.convergence import (
    convergence_table as convergence_table,
    sobol_convergence as sobol_convergence,
)
from ._sensitivity.design import sensitivity_study as sensitivity_study
from ._sensitivity.dgsm import check_dgsm_bounds as check_dgsm_bounds, dgsm as dgsm
from ._sensitivity.morris import morris_effects as morris_effects
from ._sensitivity.sobol import sobol_indices as sobol_indices
from .correlation import rank_correlations as rank_correlations
from .distributions import (
    AbstractDistribution as AbstractDistribution,
    AbstractInverseCDFDistribution as AbstractInverseCDFDistribution,
    Custom as Custom,
    LogNormal as LogNormal,
    Normal as Normal,
    TruncatedNormal as TruncatedNormal,
    Uniform as Uniform,
)
from .execution import (
    ACCELERATOR_BATCH_WIDTH as ACCELERATOR_BATCH_WIDTH,
    DEFAULT_BATCH_WIDTH as DEFAULT_BATCH_WIDTH,
    INVALID_SAMPLE as INVALID_SAMPLE,
    check_needs as check_needs,
    chunk_size_for as chunk_size_for,
    default_batch_width as default_batch_width,
    memory_budget_for as memory_budget_for,
    run_study as run_study,
)
from .lock import StoreLockedError as StoreLockedError
from .outputs import (
    Output as Output,
    elastic_force as elastic_force,
    final_pose_error as final_pose_error,
    max_deflection as max_deflection,
    object_pose as object_pose,
    peak_elastic_force as peak_elastic_force,
    peak_elastic_force_rise as peak_elastic_force_rise,
    trajectory as trajectory,
)
from .parameters import Parameter as Parameter
from .resources import (
    StudyTooLargeError as StudyTooLargeError,
    host_memory_budget as host_memory_budget,
)
from .sampling import lhs_strata as lhs_strata, sample_parameters as sample_parameters
from .sensitivity import (
    jacobian_name as jacobian_name,
    local_sensitivities as local_sensitivities,
    variance_ranking as variance_ranking,
)
from .stats import (
    exceedance_probability as exceedance_probability,
    statistics as statistics,
    summary as summary,
    valid_samples as valid_samples,
    wilson_interval as wilson_interval,
)
from .store import StoreError as StoreError, open_study as open_study
from .study import Study as Study
