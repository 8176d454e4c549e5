"""One dt of motion for every vehicle: speeds and positions along the lanes, the ego's
lateral state (``kinematics.lateral_step``); vehicles past the road's end leave it."""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import kinematics
from jaxlc.sim.road import lane_keeping_yaw_rate, lane_scales, reference_y
from jaxlc.sim.state import CRUISE, GAP, WAIT, Ego, EnvParams, Traffic


class Motion(NamedTuple):
    """Every vehicle one dt later, before inflow and phase changes."""

    x: Array  # (lanes, slots) traffic front bumpers, m
    v: Array  # (lanes, slots) traffic speeds, m/s
    active: Array  # (lanes, slots) still on the road
    ego_x: Array  # ()
    ego_y: Array  # ()
    ego_v: Array  # ()
    ego_psi: Array  # ()
    ego_omega: Array  # ()


def move(
    tr: Traffic,
    eg: Ego,
    acc: Array,
    a_ego: Array,
    a_lat: Array,
    p: EnvParams,
    kappa: Array | None = None,
) -> Motion:
    """Integrate one dt: trapezoidal positions along each lane (s advances by the distance
    over ``lane_scales``), speeds never negative; the ego's lateral state by
    ``kinematics.lateral_step``. Vehicles past the road's end (s > road_length) leave it.

    ``acc`` ``(lanes, slots)`` is the traffic's acceleration, ``a_ego`` ``()`` the ego's
    longitudinal and ``a_lat`` ``()`` its yaw acceleration.

    Before the RL phase (CRUISE, GAP) the ego holds its lane: psi = 0 and omega = kappa_d*v,
    so its y stays put on any road (on a straight one both are 0 already). In WAIT the ego is
    off the road; it coasts as on a straight road, so its numbers stay finite."""
    kappa = p.curvature if kappa is None else kappa
    dt = p.dt
    v_new = jnp.maximum(tr.v + acc * dt, 0.0)
    scale = lane_scales(kappa, p)  # a vehicle's s advances along the lane it drives in
    scale = scale[:, None] if tr.lane is None else scale[tr.lane]
    x_new = tr.x + 0.5 * (tr.v + v_new) * dt / scale
    ev = jnp.maximum(eg.v + a_ego * dt, 0.0)
    v_ego = 0.5 * (eg.v + ev)
    k_ego = jnp.where(eg.phase == WAIT, 0.0, kappa)
    holds = (eg.phase == CRUISE) | (eg.phase == GAP)
    psi = jnp.where(holds, 0.0, eg.psi)
    omega = jnp.where(holds, lane_keeping_yaw_rate(eg, v_ego, k_ego, p), eg.omega)
    ex, ey, epsi, eomega = kinematics.lateral_step(
        eg.x, eg.y, psi, omega, v_ego, a_lat, k_ego, dt, reference_y(p)
    )
    active = tr.active & (x_new <= p.road_length)
    return Motion(x_new, v_new, active, ex, ey, ev, epsi, eomega)
