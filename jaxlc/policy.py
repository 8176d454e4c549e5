"""A trained actor as a plain function, from its params or straight from a checkpoint file.

    act, meta = load_policy("runs/…/checkpoints/m01_s0/ep05000.msgpack")
    action = act(obs)  # obs (..., OBS_DIM) -> action (..., action_dim) in [-1, 1], no noise

The network comes from the checkpoint's metadata (``hidden`` and ``symmetric_actor``, written
by the sweep); a checkpoint from before those fields takes them from its run's ``config.toml``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

from jax import Array

from jaxlc import config
from jaxlc.learn.networks import actor_out_dim, make_networks
from jaxlc.study import checkpoint
from jaxlc.study.rundir import checkpoint_network


def actor_fn(
    actor_params: Any, hidden: Sequence[int], symmetric: bool = False
) -> Callable[[Array], Array]:
    """Actor params of widths ``hidden`` -> ``obs (..., OBS_DIM) -> action (..., action_dim)``
    (``symmetric``: the reflection-odd actor of ``ddpg.symmetric_actor``; the action's length
    is the params' last layer's width: 2 for ``env.longitudinal = "policy"``)."""
    cfg = config.DDPGConfig(hidden=tuple(hidden), symmetric_actor=symmetric)
    actor_net, _ = make_networks(cfg, actor_out_dim(actor_params))
    return lambda obs: actor_net.apply(actor_params, obs)


def load_policy(path: str | os.PathLike[str]) -> tuple[Callable[[Array], Array], dict[str, Any]]:
    """A checkpoint's actor as a function.

    Args:
        path: a checkpoint's ``.msgpack`` or ``.json`` (``RUN_DIR/checkpoints/mXX_sY/epNNNNN.*``).

    Returns:
        ``(act, meta)``: ``act(obs (..., OBS_DIM)) -> action (..., action_dim)`` in [-1, 1],
        and the checkpoint's metadata (its JSON).
    """
    params, meta = checkpoint.load(path)
    return actor_fn(params, *checkpoint_network(path, meta)), meta
