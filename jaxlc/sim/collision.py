"""Collisions: the ego's heading-aligned bounding box against every vehicle's box."""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import kinematics
from jaxlc.sim.leaders import vehicle_y
from jaxlc.sim.road import lane_scales
from jaxlc.sim.state import CRUISE, Ego, EnvParams, Traffic


def frame(traffic: Traffic, ego: Ego, p: EnvParams, kappa: Array | None) -> tuple:
    """``(c, lane_y, hx, hy)``: each vehicle's lane scale and lateral position (broadcast to
    ``(lanes, slots)``), the half sizes of the ego's axis-aligned box."""
    c = lane_scales(p.curvature if kappa is None else kappa, p)
    hx, hy = kinematics.half_extents(ego.psi, p.vehicle_length, p.vehicle_width)
    if traffic.lane is None:  # rows are lanes
        return c[:, None], ((jnp.arange(p.lanes) + 0.5) * p.lane_width)[:, None], hx, hy
    return c[traffic.lane], vehicle_y(traffic, p), hx, hy  # every body where it is


def overlaps(traffic: Traffic, ego: Ego, p: EnvParams, kappa: Array | None = None) -> Array:
    """``(lanes, slots)`` bool: the vehicles whose box the ego's heading-aligned bounding box
    overlaps (whatever the ego's phase); lengthwise in metres along each lane."""
    L, W = p.vehicle_length, p.vehicle_width
    c, lane_y, hx, hy = frame(traffic, ego, p, kappa)
    overlap = (jnp.abs(ego.x * c - hx - (traffic.x * c - 0.5 * L)) < hx + 0.5 * L) & (
        jnp.abs(ego.y - lane_y) < hy + 0.5 * W
    )
    return traffic.active & overlap


def clearance(traffic: Traffic, ego: Ego, p: EnvParams, kappa: Array | None = None) -> Array:
    """``(lanes, slots)`` metres between the ego's box and each vehicle's box, the boxes
    ``overlaps`` tests (inf for an inactive slot): the Euclidean distance between two
    axis-aligned boxes, lengthwise in metres along each lane; exactly 0 where they overlap
    (the evaluation's margin to collision, ``jaxlc.evaluation.measures``; not in the step)."""
    L, W = p.vehicle_length, p.vehicle_width
    c, lane_y, hx, hy = frame(traffic, ego, p, kappa)
    dx = jnp.abs(ego.x * c - hx - (traffic.x * c - 0.5 * L)) - (hx + 0.5 * L)
    dy = jnp.abs(ego.y - lane_y) - (hy + 0.5 * W)
    gap = jnp.hypot(jnp.maximum(dx, 0.0), jnp.maximum(dy, 0.0))
    return jnp.where(traffic.active, gap, jnp.inf)


def collided(
    traffic: Traffic, ego: Ego, spawned: Array, p: EnvParams, kappa: Array | None = None
) -> Array:
    """``()`` bool: the ego's box overlaps a vehicle's box (a just spawned ego, at the road's
    start, is not checked)."""
    return (ego.phase >= CRUISE) & ~spawned & jnp.any(overlaps(traffic, ego, p, kappa))
