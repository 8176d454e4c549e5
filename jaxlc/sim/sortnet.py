"""A sorting network for the short rows the traffic sorts every step (``leaders.around``).

Batcher's bitonic network on the next power of two: ``log2(m) * (log2(m) + 1) / 2``
compare-exchange stages of ``m / 2`` elementwise min/max pairs each, with static shapes and no
data-dependent branch, so that under ``vmap`` every stage is one elementwise pass over the
batch, where XLA's CPU sort runs a comparison sort per row
(``benchmarks/bench_traffic_sortnet_cpu_2026-11-27``).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array


def sort(x: Array) -> Array:
    """``x`` ``(..., n)`` integer keys sorted ascending along the last axis (``jnp.sort``'s
    result, element for element)."""
    n = x.shape[-1]
    m = 1 << max(1, (n - 1).bit_length())
    batch = x.shape[:-1]
    pad = jnp.full((*batch, m - n), jnp.iinfo(x.dtype).max, x.dtype)  # sorts last
    y = jnp.concatenate([x, pad], axis=-1)  # (..., m)
    k = 2
    while k <= m:  # static: bitonic runs of length k, merged at distances k/2, k/4, ..., 1
        d = k // 2
        while d >= 1:
            z = y.reshape(*batch, m // (2 * d), 2, d)  # pairs (i, i + d) in blocks of 2d
            a, b = z[..., 0, :], z[..., 1, :]
            lo, hi = jnp.minimum(a, b), jnp.maximum(a, b)
            up = ((jnp.arange(m // (2 * d)) * 2 * d) // k % 2 == 0)[:, None]  # (m/2d, 1)
            first, second = jnp.where(up, lo, hi), jnp.where(up, hi, lo)
            y = jnp.stack([first, second], axis=-2).reshape(*batch, m)
            d //= 2
        k *= 2
    return y[..., :n]
