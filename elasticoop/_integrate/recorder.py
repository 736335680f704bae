"""The record of a solve's accepted steps, kept by the step-size controller: what the
stepwise adjoint replays (`adjoint.py`), and the interface a controller offers to
keep it (`AbstractStepRecorder`, implemented by `controller.StopFailedSteps`).

The record is kept by the controller rather than by diffrax's
`SaveAt(steps=True)`, so that the forward half of a gradient costs about as much as
a forward run that keeps nothing (`benchmarks/gradients.py`).
"""

import abc
from typing import Any, NamedTuple

import diffrax
import jax.numpy as jnp
from jaxtyping import Array, Float, Int, PyTree


class StepLayout(NamedTuple):
    """Where the record of a run's accepted steps keeps each step's start state.

    The first `kept` steps each have a slot; the next `2 kept` steps every second
    one, the next `4 kept` every fourth, and so on: level $l \\ge 0$ holds the
    steps $n$ with $\\text{kept}\\,(2^l - 1) \\le n < \\text{kept}\\,(2^{l+1} - 1)$
    in `kept` slots, each step whose offset in its level is a multiple of $2^l$.
    `levels` levels hold `max_steps` steps (the times of every step are kept).
    A step without a slot writes the spare slot after the last (`spare`)."""

    kept: int
    levels: int
    max_steps: int

    @classmethod
    def of(cls, max_steps: int, kept: int) -> "StepLayout":
        """The layout for a run of at most `max_steps` steps that keeps the first
        `kept` steps' start states."""
        kept = max(1, min(kept, max_steps))
        levels = 1
        while kept * (2**levels - 1) < max_steps:
            levels += 1
        return cls(kept, levels, max_steps)

    @property
    def spare(self) -> int:
        """The slot that the steps without a slot of their own write."""
        return self.kept * self.levels

    def _level(self, n: Int[Array, ""]) -> tuple[Array, Array]:
        """The level of step `n`, and the step's offset in it."""
        n = jnp.asarray(n, jnp.int32)
        level = jnp.zeros((), jnp.int32)
        for lvl in range(1, self.levels):
            level = level + (n >= self.kept * (2**lvl - 1)).astype(jnp.int32)
        return level, n - self.kept * (jnp.left_shift(1, level) - 1)

    def checkpoint(self, n: Int[Array, ""]) -> tuple[Array, Array]:
        """The last step at or before step `n` with a slot, and that slot."""
        level, offset = self._level(n)
        back = jnp.bitwise_and(offset, jnp.left_shift(1, level) - 1)
        slot = level * self.kept + jnp.right_shift(offset, level)
        return jnp.asarray(n, jnp.int32) - back, slot

    def slot(self, n: Int[Array, ""]) -> Int[Array, ""]:
        """The slot of step `n`'s start state (`spare` if it has none)."""
        start, slot = self.checkpoint(n)
        return jnp.where(start == n, slot, self.spare)


class AcceptedSteps(NamedTuple):
    """The accepted steps of a solve, as `StepwiseAdjoint` replays them: how many,
    and for each step $n$ (rows past the last are padding) its start time $t_n$
    and end time, and the start states $x_n$ of the steps that have a slot in the
    `StepLayout` (a leading axis of `spare + 1` rows on each leaf)."""

    n_accepted: Int[Array, ""]
    t_start: Float[Array, " rows"]
    t_end: Float[Array, " rows"]
    y_start: PyTree[Array]


class AbstractStepRecorder(diffrax.AbstractAdaptiveStepSizeController):
    """A step-size controller that can keep the accepted steps in its state, what
    `StepwiseAdjoint` needs of `integrate`'s controller.

    (Kept by the controller rather than by diffrax's `SaveAt(steps=True)`, which
    makes the forward half of a gradient slower; this way it costs about as much
    as a forward run that keeps nothing: `benchmarks/gradients.py`.)"""

    @abc.abstractmethod
    def recording(self, layout: StepLayout) -> "AbstractStepRecorder":
        """This controller, keeping the accepted steps in `layout`."""

    @property
    @abc.abstractmethod
    def records(self) -> bool:
        """Whether this controller keeps the accepted steps (a `recording`)."""

    @abc.abstractmethod
    def accepted_steps(self, state: Any) -> tuple[AcceptedSteps, Any]:
        """The steps a `recording` controller kept, from its final `state`, and
        that state as the controller would have ended it without recording."""

    @abc.abstractmethod
    def with_accepted_steps(self, state: Any, steps: AcceptedSteps | None) -> Any:
        """`state`, without the steps (`accepted_steps`), with `steps` again."""
