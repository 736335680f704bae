"""The few multi-process operations a study needs (`jax.experimental.multihost_utils`).

A study spread over several processes (started with `jax.distributed.initialize`)
runs every chunk as one global array sharded over all devices of all processes;
these helpers bring the results to the host and keep the processes in step. With a
single process they reduce to plain NumPy conversions.
"""

import jax
import numpy as np
from jax.experimental import multihost_utils


def is_first_process() -> bool:
    return jax.process_index() == 0


def gather(tree):
    """Every process gets the full (global) arrays of `tree` as NumPy arrays."""
    if jax.process_count() == 1:
        return jax.tree.map(np.asarray, jax.device_get(tree))
    return jax.tree.map(np.asarray, multihost_utils.process_allgather(tree, tiled=True))


def broadcast_from_first(value: np.ndarray) -> np.ndarray:
    """The first process's `value` on every process (same shape everywhere)."""
    if jax.process_count() == 1:
        return value
    return np.asarray(multihost_utils.broadcast_one_to_all(value))


def barrier(name: str) -> None:
    """Wait until every process reaches this point."""
    if jax.process_count() > 1:
        multihost_utils.sync_global_devices(name)
