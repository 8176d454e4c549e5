"""Several processes, one run: JAX's distributed runtime started from the environment, and
arrays gathered whole onto every process (``--distributed``; docs/operations.md)."""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
from jax.experimental import multihost_utils

from jaxlc import config


def to_host(tree: Any) -> Any:
    """Numpy copy of a pytree of (possibly sharded) arrays, whole on every process."""
    if jax.process_count() == 1:
        return jax.device_get(tree)

    def whole(a: Any) -> np.ndarray:
        # host data (e.g. a state read back for --resume) is already whole on every process
        if not isinstance(a, jax.Array):
            return np.asarray(a)
        return np.asarray(multihost_utils.process_allgather(a, tiled=True))

    return jax.tree.map(whole, tree)


def distributed_init() -> None:
    """``jax.distributed.initialize`` from the usual environment: JAX_COORDINATOR_ADDRESS,
    JAX_NUM_PROCESSES and JAX_PROCESS_ID when set, else JAX's own detection (Slurm, Open
    MPI)."""
    env = os.environ
    try:
        n = int(env["JAX_NUM_PROCESSES"]) if "JAX_NUM_PROCESSES" in env else None
        pid = int(env["JAX_PROCESS_ID"]) if "JAX_PROCESS_ID" in env else None
    except ValueError:
        raise config.ConfigError(
            "--distributed: JAX_NUM_PROCESSES and JAX_PROCESS_ID must be integers"
        ) from None
    try:
        jax.distributed.initialize(num_processes=n, process_id=pid)
    except (ValueError, RuntimeError) as err:
        raise config.ConfigError(
            f"--distributed: cannot start JAX's distributed runtime ({err}); set "
            "JAX_COORDINATOR_ADDRESS, JAX_NUM_PROCESSES and JAX_PROCESS_ID, or run under Slurm"
        ) from None
