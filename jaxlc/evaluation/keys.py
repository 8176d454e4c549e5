"""Every key stream of the evaluation, from one function: ``stream(seed, purpose, indices)``.

Case ``i`` of a stream is ``fold_in(root, i)``, so it is the same however many cases are
drawn and whichever chunk draws it. The protocol's root is ``PRNGKey(seed)``; every other
purpose folds its tag into that root first, so its keys are a stream of their own, apart
from the protocol's and from the sweep's (splits of ``PRNGKey(0)`` with each model's seed
folded in): a key shared by chance is as likely as a hash collision (tests/test_heldout.py
finds none among the first 2,000 of seeds 0-2).

Committed files name the streams by the functions that made them before this module:
``jaxlc.evaluation.cases.heldout_keys(seed, n)`` (``heldout.json``'s ``key_stream``, the
reports) is ``stream(seed, HELDOUT, range(n))``, ``case_keys(seed, n)`` the protocol's,
``validation.validate_keys(seed, tag, lo, n)`` ``stream(seed, VALIDATE or PILOT,
range(lo, lo + n))`` and ``keys_at(seed, tag, indices)`` the same at a saved case's indices.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

PROTOCOL = "protocol"  # the fixed cases every checkpoint meets (eval.json)
HELDOUT = "heldout"  # the held-out lane changes (heldout.json)
VALIDATE = "validate"  # the failure-probability estimate's cases (jaxlc.validate)
PILOT = "pilot"  # the cross-entropy fit's pilot chunks
# Each purpose's tag folded into the seed's root (the protocol's: none).
TAGS: dict[str, int | None] = {
    PROTOCOL: None,
    HELDOUT: 0x48454C44,  # "HELD"
    VALIDATE: 0x56414C44,  # "VALD"
    PILOT: 0x50494C54,  # "PILT"
}


def stream(seed: int, purpose: str, indices: Any) -> Array:
    """``(len(indices), 2)`` keys of ``purpose``'s stream of ``seed`` at ``indices`` (a
    range, a list of saved case indices, an array)."""
    root = jax.random.PRNGKey(seed)
    if TAGS[purpose] is not None:
        root = jax.random.fold_in(root, TAGS[purpose])
    idx = jnp.asarray(np.asarray(indices, np.int64) if isinstance(indices, range) else indices)
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(idx)
