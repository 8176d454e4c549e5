"""A trained actor as a plain function, from its params or straight from a checkpoint file.

    act, meta = load_policy("runs/…/checkpoints/m01_s0/ep05000.msgpack")
    action = act(obs)  # obs (..., OBS_DIM) -> action (..., 1) in [-1, 1], no noise

The network comes from the checkpoint's metadata (``hidden`` and ``symmetric_actor``, written
by the sweep); a checkpoint from before those fields takes them from its run's ``config.toml``.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from jax import Array

from jaxlc import config
from jaxlc.learn.networks import make_networks
from jaxlc.sim.env import ACT_DIM
from jaxlc.study import checkpoint
from jaxlc.study.rundir import RunDir


def actor_fn(
    actor_params: Any, hidden: Sequence[int], symmetric: bool = False
) -> Callable[[Array], Array]:
    """Actor params of widths ``hidden`` -> ``obs (..., OBS_DIM) -> action (..., 1)``
    (``symmetric``: the reflection-odd actor of ``ddpg.symmetric_actor``)."""
    cfg = config.DDPGConfig(hidden=tuple(hidden), symmetric_actor=symmetric)
    actor_net, _ = make_networks(cfg, ACT_DIM)
    return lambda obs: actor_net.apply(actor_params, obs)


def network(path: str | os.PathLike[str], meta: dict[str, Any]) -> tuple[tuple[int, ...], bool]:
    """``(hidden, symmetric_actor)`` of the checkpoint at ``path`` (metadata ``meta``); a
    checkpoint that records its widths but not ``symmetric_actor`` predates that option."""
    if "hidden" in meta:
        return tuple(int(h) for h in meta["hidden"]), bool(meta.get("symmetric_actor", False))
    run = RunDir(Path(path).resolve().parents[2])  # RUN_DIR/checkpoints/mXX_sY/file
    if run.is_run():
        d = run.load_config().ddpg
        return tuple(d.hidden), d.symmetric_actor
    raise checkpoint.CheckpointError(
        f"checkpoint {path} records no network widths ('hidden') and has no run directory "
        "two levels up; build the function with jaxlc.policy.actor_fn(params, hidden)"
    )


def load_policy(path: str | os.PathLike[str]) -> tuple[Callable[[Array], Array], dict[str, Any]]:
    """``(act, meta)`` of a checkpoint: its actor as a function, and its metadata."""
    params, meta = checkpoint.load(path)
    return actor_fn(params, *network(path, meta)), meta
