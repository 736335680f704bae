"""The step budget of the simulations during a fit.

A trial point that needs many more solver steps than the point the fit stands at
is far off (much stiffer, or lightly damped at high frequency): rather than
integrating it to the end, its simulation stops at the budget and the trial is
rejected like a failed simulation. The budget follows the fit: it is set from the
steps the start needs and raised whenever an accepted point needs more than
1/`STEP_BUDGET_FACTOR` of it, so that it never keeps the fit from points that
need more steps than the start did.

The starting points are simulated under the budget of a start that needs few
steps (`step_budget(0, max_steps)`: `MIN_BUDGET`, or `max_steps` where that is
less than twice it), and a start that reaches it again under the simulation
settings' `max_steps`. The budget is a traced value (`FitProblem.step_budget`):
the starts, the fit and every raise of its budget run one compiled program.
"""

import dataclasses
import math

from .residuals import FitProblem, with_step_budget

# Solver steps allowed for the simulations at the start, and the most any later
# simulation is allowed.
START_MAX_STEPS = 100_000
# The budget is this multiple of the steps the current point needs ...
STEP_BUDGET_FACTOR = 8
# ... and at least this (trials close to a cheap point cost little anyway).
MIN_BUDGET = 4096


def step_budget(steps: int, cap: int = START_MAX_STEPS) -> int:
    """The budget of trial simulations near a point whose simulations took `steps`
    solver steps: `STEP_BUDGET_FACTOR` times `steps`, at least `MIN_BUDGET`,
    rounded up to a power of 2 (a raise at least doubles it), and `cap` (the
    simulation settings' `max_steps`) where that is more than half of `cap`."""
    wanted = max(MIN_BUDGET, math.ceil(STEP_BUDGET_FACTOR * int(steps)))
    budget = 1 << (wanted - 1).bit_length()
    return cap if 2 * budget > cap else budget


@dataclasses.dataclass
class StepBudget:
    """The step budget of a fit: fixed (`adaptive=False`: the caller's
    `max_sim_steps`), or set by `start` and raised by `follow` as the fit moves to
    points that need more steps. `notes` says what was set, `raised_to` is the last
    budget `follow` set (None: never raised)."""

    adaptive: bool
    cap: int = START_MAX_STEPS
    notes: list[str] = dataclasses.field(default_factory=list)
    raised_to: int | None = None

    def start(self, problem: FitProblem, steps: int) -> FitProblem:
        """`problem` with the budget for a start whose simulations took `steps`
        solver steps (unchanged when the budget is fixed)."""
        if not self.adaptive:
            return problem
        budget = step_budget(steps, self.cap)
        if budget >= self.cap:
            return with_step_budget(problem, self.cap)
        self.notes.append(
            f"simulations limited to {budget} solver steps ({STEP_BUDGET_FACTOR}x "
            f"those at the start, at least {MIN_BUDGET}, raised as the fit reaches "
            f"points that need more, up to {self.cap}); a trial point "
            f"needing more is rejected"
        )
        return with_step_budget(problem, budget)

    def follow(self, problem: FitProblem, steps: int, iteration: int) -> FitProblem:
        """`problem` with the budget that an accepted point needing `steps` solver
        steps calls for (the same problem when its budget suffices)."""
        current = problem.max_steps
        budget = step_budget(steps, self.cap)
        if not self.adaptive or budget <= current:
            return problem
        self.raised_to = budget
        self.notes.append(
            f"step budget raised from {current} to {budget} at iteration "
            f"{iteration}, where the simulations took {steps} solver steps"
        )
        return with_step_budget(problem, budget)
