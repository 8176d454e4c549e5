"""The drawn cases' frames: the ego and its traffic at each RL step of a few cases
(``pick_traced``), written by the rollout (``jaxlc.evaluation.engine``) for the figures."""

from __future__ import annotations

from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxlc.sim.env import EnvParams, EnvState
from jaxlc.sim.leaders import vehicle_y
from jaxlc.sim.road import road_curvature


@flax.struct.dataclass
class Trace:
    """The drawn cases, frame 0 = start of the RL phase: ``(policies, traced, frames, ...)``;
    frames past a case's ``frames`` are 0."""

    x: Array  # ego front bumper, m
    y: Array  # ego centre line, m
    psi: Array
    v: Array  # ego speed, m/s
    frames: Array  # (policies, traced) int32 valid frames
    traffic_x: Array  # (..., lanes, slots)
    traffic_active: Array  # (..., lanes, slots) bool
    traffic_y: Array  # (..., lanes, slots) body centre lines, m (between lanes while changing)
    lead_x: Array  # target-lane lead vehicle (front bumper), valid where has_lead
    lag_x: Array
    has_lead: Array
    has_lag: Array
    curvature: Array  # (policies, traced) the case's road curvature, 1/m (figures bend it)


def empty(n_pol: int, n_traced: int, frames: int, p: EnvParams) -> Trace:
    shape = (n_pol, n_traced, frames)
    lanes = shape + (p.lanes, p.slots_per_lane)
    f, b = jnp.zeros(shape, jnp.float32), jnp.zeros(shape, bool)
    return Trace(
        x=f,
        y=f,
        psi=f,
        v=f,
        frames=jnp.zeros(shape[:2], jnp.int32),
        traffic_x=jnp.zeros(lanes, jnp.float32),
        traffic_active=jnp.zeros(lanes, bool),
        traffic_y=jnp.zeros(lanes, jnp.float32),
        lead_x=f,
        lag_x=f,
        has_lead=b,
        has_lag=b,
        curvature=jnp.zeros(shape[:2], jnp.float32),
    )


def record(
    trace: Trace, i: Array | int, state: EnvState, traced: Array, live: Array, p: EnvParams
) -> Trace:
    """Write frame ``i`` of the traced cases, ``state``'s cases ``traced``, where ``live``
    ``(policies, traced)``, and count it there."""
    st = jax.tree.map(lambda a: a[:, traced], state)
    eg, tr, nb = st.ego, st.traffic, st.nb
    values = {
        "x": eg.x,
        "y": eg.y,
        "psi": eg.psi,
        "v": eg.v,
        "traffic_x": tr.x,
        "traffic_active": tr.active,
        "traffic_y": jax.vmap(jax.vmap(vehicle_y, (0, None)), (0, None))(tr, p),
        "lead_x": nb.a1_x,
        "lag_x": nb.b1_x,
        "has_lead": nb.has_a1,
        "has_lag": nb.has_b1,
    }

    def keep(old: Array, new: Array) -> Array:  # (policies, traced, ...) where live
        return jnp.where(live.reshape(live.shape + (1,) * (new.ndim - 2)), new, old)

    new = {
        k: getattr(trace, k).at[:, :, i].set(keep(getattr(trace, k)[:, :, i], v))
        for k, v in values.items()
    }
    kappa = jnp.broadcast_to(road_curvature(st, p), eg.x.shape).astype(jnp.float32)
    return trace.replace(
        **new, frames=trace.frames + live.astype(jnp.int32), curvature=keep(trace.curvature, kappa)
    )


def pick_traced(cases: Any, n: int) -> np.ndarray:
    """Up to ``n`` performed cases to draw, alternating left and right lane changes (``cases``:
    an ``engine.Cases``, its ``side`` and ``performed`` ``(cases,)``)."""
    side, performed = np.asarray(cases.side), np.asarray(cases.performed)
    left = list(np.nonzero(performed & (side > 0))[0])
    right = list(np.nonzero(performed & (side < 0))[0])
    picked: list[int] = []
    while len(picked) < n and (left or right):
        for group in (left, right):
            if group and len(picked) < n:
                picked.append(int(group.pop(0)))
    return np.asarray(picked or [0], np.int32)  # one case at least keeps shapes non-empty
