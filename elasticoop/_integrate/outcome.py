"""What a solve of `simulate` returns (`Outcome`), from diffrax's loop or the batch
loop."""

from typing import Any

import diffrax
import equinox as eqx
import jax
from jaxtyping import Array, Bool, Float, Int, PyTree


# (`Any`: a type checker takes the items of an `equinox.Enumeration` for strings)
def results_where(pred: Bool[Array, "*batch"], a: Any, b: Any) -> Any:
    """`diffrax.RESULTS.where` of a batch: `a` where `pred`, else `b`, sample by
    sample (each of `a`, `b` one item or a batch of them)."""
    if pred.ndim == 0:
        return diffrax.RESULTS.where(pred, a, b)
    axes = [0 if jax.tree.leaves(x)[0].ndim else None for x in (a, b)]
    return jax.vmap(results_where, in_axes=(0, *axes))(pred, a, b)


class Outcome(eqx.Module):
    """What `simulate` reads of a solve: the states at `ts` then at the end (`ts`
    is inf past the end, as diffrax leaves it), diffrax's `RESULTS` code, which
    stop condition ended the run, the controller's final state and the number of
    steps tried. A leading batch axis where the batch loop made it."""

    ts: Float[Array, "*batch saves"]
    ys: PyTree[Array]
    result: diffrax.RESULTS
    event_mask: tuple[Bool[Array, "*batch"], ...]
    controller_state: PyTree
    num_steps: Int[Array, "*batch"]
