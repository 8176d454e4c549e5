"""Pytree selection: the one ``where`` over whole pytrees that the trainer and evaluation use."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from jax import Array


def where(mask: Array, new: Any, old: Any) -> Any:
    """``jnp.where(mask, new, old)`` leaf by leaf, for pytrees of the same structure.

    ``mask`` is a () bool (one choice for the whole tree) or has the leading axes of every
    leaf (one choice per row, e.g. ``(policies, cases)``); it broadcasts over the rest.
    """

    def pick(n: Array, o: Array) -> Array:
        m = jnp.reshape(mask, jnp.shape(mask) + (1,) * (jnp.ndim(n) - jnp.ndim(mask)))
        return jnp.where(m, n, o)

    return jax.tree.map(pick, new, old)
