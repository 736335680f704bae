"""Parameter identification: fit stiffness, damping (or any leaves of a model) to
measured motion, with uncertainty and identifiability."""

from .differentiate import savitzky_golay as savitzky_golay
from .equation_error import equation_error as equation_error
from .experiment import Experiment as Experiment
from .identify import identify as identify
from .initial_state import initial_state_from_data as initial_state_from_data
from .misfit import MisfitCheck as MisfitCheck
from .parameters import (
    AbstractTransform as AbstractTransform,
    Bounded as Bounded,
    Identity as Identity,
    Log as Log,
    Softplus as Softplus,
)
from .result import (
    IdentificationResult as IdentificationResult,
    ParameterRow as ParameterRow,
)
from .uncertainty import (
    Uncertainty as Uncertainty,
    gauss_newton_uncertainty as gauss_newton_uncertainty,
)
