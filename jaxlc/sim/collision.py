"""Collisions: the ego's heading-aligned bounding box against every vehicle's box."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import kinematics
from jaxlc.sim.leaders import vehicle_y
from jaxlc.sim.road import lane_scales
from jaxlc.sim.state import CRUISE, Ego, EnvParams, Traffic


def overlaps(traffic: Traffic, ego: Ego, p: EnvParams, kappa: Array | None = None) -> Array:
    """``(lanes, slots)`` bool: the vehicles whose box the ego's heading-aligned bounding box
    overlaps (whatever the ego's phase); lengthwise in metres along each lane."""
    L, W = p.vehicle_length, p.vehicle_width
    c = lane_scales(p.curvature if kappa is None else kappa, p)
    hx, hy = kinematics.half_extents(ego.psi, L, W)
    if traffic.lane is None:  # rows are lanes
        c = c[:, None]
        lane_y = ((jnp.arange(p.lanes) + 0.5) * p.lane_width)[:, None]
    else:  # every body where it is, one changing lanes between two
        c, lane_y = c[traffic.lane], vehicle_y(traffic, p)
    overlap = (jnp.abs(ego.x * c - hx - (traffic.x * c - 0.5 * L)) < hx + 0.5 * L) & (
        jnp.abs(ego.y - lane_y) < hy + 0.5 * W
    )
    return traffic.active & overlap


def collided(
    traffic: Traffic, ego: Ego, spawned: Array, p: EnvParams, kappa: Array | None = None
) -> Array:
    """``()`` bool: the ego's box overlaps a vehicle's box (a just spawned ego, at the road's
    start, is not checked)."""
    return (ego.phase >= CRUISE) & ~spawned & jnp.any(overlaps(traffic, ego, p, kappa))
