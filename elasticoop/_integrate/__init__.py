"""The ODE engine of `simulate`: it knows diffrax and knows no bodies.

- `solve.integrate`: `diffrax.diffeqsolve` with the setup `simulate` uses, or, under
  `jax.vmap`, one loop over the whole batch (`batch_loop.py`, stepping with
  `rk_step.py`), differentiated in reverse mode through the accepted steps
  (`adjoint.py`, replaying the steps the controller recorded: `recorder.py`).
- `controller.StopFailedSteps`: the step-size controller (a clean stop where no step
  can succeed, a record of the steps); `error_norm.rms_norm`: its error norm.
- `events.locate_event`: where in its last step a run stopped.
- `stability.stability_radius`: how long a step of a method may be and stay stable.
- `outcome.Outcome`: what a solve returns.
"""

from .adjoint import (
    StepwiseAdjoint as StepwiseAdjoint,
    default_adjoint as default_adjoint,
)
from .batch_loop import default_lanes as default_lanes
from .controller import (
    MIN_STEP_ULPS as MIN_STEP_ULPS,
    StopFailedSteps as StopFailedSteps,
)
from .error_norm import rms_norm as rms_norm
from .events import locate_event as locate_event
from .outcome import Outcome as Outcome
from .solve import integrate as integrate
from .stability import stability_radius as stability_radius
