from .closed_loop_rest import (
    closed_loop_residual as closed_loop_residual,
    closed_loop_rest as closed_loop_rest,
    closed_loop_stiffness as closed_loop_stiffness,
)
from .equilibrium import (
    Equilibrium as Equilibrium,
    static_equilibrium as static_equilibrium,
)
from .inverse import inverse_dynamics_series as inverse_dynamics_series
from .linear import (
    LinearModel as LinearModel,
    StateSpace as StateSpace,
    linearize as linearize,
)
from .load_distribution import (
    LoadDistribution as LoadDistribution,
    grasp_matrix as grasp_matrix,
    grasp_wrenches as grasp_wrenches,
    load_distribution as load_distribution,
    trajectory_load_distribution as trajectory_load_distribution,
)
from .modes import Modes as Modes, modes as modes
from .rest_state import (
    contact_bodies_held as contact_bodies_held,
    rest_state as rest_state,
)
