"""The machine a run is on: the host-device layout that trains fastest on a CPU, and the
float32 matmul peak that lets a reader scale a wall time from one machine to another.

XLA runs a CPU computation on one device; ``--xla_force_host_platform_device_count=N``
splits the CPU into N host devices, and the sweep lays its models over them with
``shard_map`` (``train.make_grid_fns``), each block of models in a program of its own. That
flag is read once, when JAX starts its backends, so ``use_host_devices`` must run before the
first JAX computation of the process (the CLIs call it first thing).
"""

from __future__ import annotations

import os
import statistics
import time

import jax
import jax.numpy as jnp

HOST_DEVICES_FLAG = "--xla_force_host_platform_device_count"


# Below this many multiply-adds in a program's largest matrix product, per-op dispatch rules
# its time and more host devices only add overhead; above it the products rule and more
# devices run them side by side on the cores.
SMALL_PRODUCT = 1 << 20


def largest_product(rows: int, widths: tuple[int, ...]) -> int:
    """Multiply-adds of the largest product of an MLP of layer ``widths`` over ``rows``."""
    return rows * max(a * b for a, b in zip(widths, widths[1:], strict=False))


def host_devices_for(models: int, product: int, cores: int | None = None) -> int:
    """Host devices to lay ``models`` over on a CPU of ``cores`` cores, for a program whose
    largest matrix product is ``product`` multiply-adds: one when that is small
    (``SMALL_PRODUCT``), else the largest divisor of ``models`` (so no padded copies run) up
    to ``cores + 1`` (the timings behind the rule: docs/decisions.md, "host devices on a
    CPU"). ``cores``: default, the cores this process may run on."""
    if product < SMALL_PRODUCT:
        return 1
    cores = cores or len(os.sched_getaffinity(0))  # the cores this process may run on
    return max(d for d in range(1, min(models, cores + 1) + 1) if models % d == 0)


def use_host_devices(n: int) -> bool:
    """Ask XLA for ``n`` CPU host devices unless the user's ``XLA_FLAGS`` already sets the
    count or JAX has started (then the flag could not take effect). Returns whether it was
    set. Harmless on a GPU machine: the flag shapes only the CPU platform."""
    flags = os.environ.get("XLA_FLAGS", "")
    if n < 1 or HOST_DEVICES_FLAG in flags or _backends_started():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {HOST_DEVICES_FLAG}={n}".strip()
    return True


def _backends_started() -> bool:
    """Whether JAX has started its backends (private API: a JAX that moved it reads as not
    started, and the flag then at worst takes no effect)."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):
        return False


def matmul_peak_gflops(n: int = 2048, repeats: int = 5) -> float:
    """GFLOP/s of a jitted float32 ``(n, n) @ (n, n)`` on JAX's first device, median of
    ``repeats`` calls after one to compile: the machine's speed for the work a DDPG update is
    made of."""
    ka, kb = jax.random.split(jax.random.key(0))
    a = jax.random.normal(ka, (n, n), jnp.float32)
    b = jax.random.normal(kb, (n, n), jnp.float32)
    dot = jax.jit(jnp.dot)
    jax.block_until_ready(dot(a, b))
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        jax.block_until_ready(dot(a, b))
        times.append(time.perf_counter() - t0)
    return 2 * n**3 / statistics.median(times) / 1e9
