"""A trained actor as a plain function, from its params or straight from a checkpoint file.

    act, meta = load_policy("runs/…/checkpoints/m01_s0/ep05000.msgpack")
    action = act(obs)  # obs (..., OBS_DIM) -> action (..., action_dim) in [-1, 1], no noise

The network comes from the checkpoint's metadata (``hidden`` and ``symmetric_actor``, written
by the sweep); a checkpoint from before those fields takes them from its run's ``config.toml``.

Out of JAX (``python -m jaxlc.export``): ``onnx_model`` and ``stablehlo_bytes`` convert that
same function, and ``sidecar`` is the JSON written beside it (the observation layout, the
action's meaning, bound and scale, the checkpoint it came from).
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
from jax import Array

from jaxlc import config
from jaxlc.learn.networks import actor_out_dim, make_networks
from jaxlc.sim import observation
from jaxlc.sim.env import ACTION_MIRROR, OBS_DIM, EnvParams, action_dim
from jaxlc.sim.observation import LAYOUT
from jaxlc.study import checkpoint
from jaxlc.study.rundir import RunDir, checkpoint_network

OPSET = 17  # of the ONNX graph: onnxruntime 1.17 and later run it


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


def sidecar(path: Path, meta: dict[str, Any], run_dir: Path, fmt: str) -> dict[str, Any]:
    """The JSON written beside the exported graph (module docstring)."""
    params = EnvParams.from_config(RunDir(run_dir).load_config().env)
    return {
        "format": fmt,
        "input": {
            "name": "obs",
            "shape": ["batch", OBS_DIM],
            "dtype": "float32",
            "layout": [
                {
                    "index": i,
                    "name": e.name,
                    "meaning": observation.meaning(e, params),
                    "scale": float(observation.scale(e.name, params)),
                    "mirror_sign": e.mirror,
                }
                for i, e in enumerate(LAYOUT)
            ],
            "note": "entry i is the raw quantity divided by its scale, as the env returns it",
        },
        "output": {
            "name": "action",
            "shape": ["batch", action_dim(params)],
            "dtype": "float32",
            "meaning": "yaw acceleration command of the ego, held for k steps of dt",
            "bound": [-1.0, 1.0],
            "scale": float(params.max_yaw_acc),
            "unit": "rad/s^2 (physical yaw acceleration = action * scale)",
            "k": meta["k"],
            "dt_s": float(params.dt),
            **_longitudinal(params),
            **_assist(params),
        },
        "symmetric_actor": bool(meta.get("symmetric_actor", False)),
        "checkpoint": str(path.relative_to(run_dir)),
        "model": meta["model"],
        "label": meta["label"],
        "seed": meta.get("seed"),
        "episode": meta["episode"],
        "config_hash": meta["config_hash"],
        "jaxlc_version": meta["jaxlc_version"],
    }


def _longitudinal(params: EnvParams) -> dict[str, Any]:
    """The second action entry's meaning, where the run's ego has one (``env.longitudinal =
    "policy"``)."""
    if action_dim(params) == 1:
        return {}
    return {
        "entries": [
            {
                "index": 0,
                "meaning": "yaw acceleration",
                "scale": float(params.max_yaw_acc),
                "unit": "rad/s^2",
                "mirror_sign": ACTION_MIRROR[0],
            },
            {
                "index": 1,
                "meaning": "longitudinal acceleration added to the IDM's "
                "(within [-idm_b_max, idm_a_max], never past the desired speed)",
                "scale": float(params.long_acc_bound),
                "unit": "m/s^2",
                "mirror_sign": ACTION_MIRROR[1],
            },
        ],
    }


def _assist(params: EnvParams) -> dict[str, Any]:
    """What the run's env adds to the graph's action (``env.assist``), where it adds any: the
    graph alone is then a residual, not the driving policy."""
    if params.assist == "none":
        return {}
    return {
        "assist": params.assist,
        "assist_authority": float(params.assist_authority),
        "assist_note": "the executed action is clip(assist_authority * action + jaxlc.sim."
        "controller.fitting_action(obs, params, time=manoeuvre time), -1, 1): this graph is "
        "the residual"
        + (
            "; while the assist holds the origin lane, the lateral entry is the assist's alone"
            if params.assist == "fitting_hold"
            else ""
        ),
    }


def onnx_model(act: Any) -> Any:
    """``act`` (``(batch, OBS_DIM) -> (batch, action_dim)``) as an ONNX ``ModelProto`` with a
    dynamic batch dimension, input ``obs`` and output ``action``."""
    from jax2onnx import to_onnx  # the export extra; imported only here

    return to_onnx(
        act,
        [("batch", OBS_DIM)],
        model_name="jaxlc_actor",
        opset=OPSET,
        input_names=["obs"],
        output_names=["action"],
    )


def stablehlo_bytes(act: Any) -> bytes:
    """``act`` serialised by ``jax.export`` with a symbolic batch dimension."""
    (batch,) = jax.export.symbolic_shape("batch")
    spec = jax.ShapeDtypeStruct((batch, OBS_DIM), jnp.float32)
    return bytes(jax.export.export(jax.jit(act))(spec).serialize())
