"""What a solve of `simulate` returns (`Outcome`), from diffrax's loop or the batch
loop, and the integers of diffrax's `RESULTS` it holds."""

from typing import Any

import diffrax
import equinox as eqx
from jaxtyping import Array, Bool, Float, Int, PyTree


def result_code(result: Any) -> int:
    """The integer of one of diffrax's `RESULTS`, as `Outcome.result` holds it."""
    return int(result._value)


SUCCESSFUL = result_code(diffrax.RESULTS.successful)
EVENT_OCCURRED = result_code(diffrax.RESULTS.event_occurred)
MAX_STEPS_REACHED = result_code(diffrax.RESULTS.max_steps_reached)


class Outcome(eqx.Module):
    """What `simulate` reads of a solve: the states at `ts` then at the end (`ts`
    is inf past the end, as diffrax leaves it), diffrax's `RESULTS` code, which
    stop condition ended the run, the controller's final state and the number of
    steps tried. A leading batch axis where the batch loop made it."""

    ts: Float[Array, "*batch saves"]
    ys: PyTree[Array]
    result: Int[Array, "*batch"]
    event_mask: tuple[Bool[Array, "*batch"], ...]
    controller_state: PyTree
    num_steps: Int[Array, "*batch"]
