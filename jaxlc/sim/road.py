"""The road's geometry: lanes, their centre lines and scales, and where the ego is on them.

Positions are Frenet (``kinematics``): x = s along the road's centre line (the reference line,
at y = lanes*W/2), y across it. A lane's net gaps are metres along its own centre line: s
times its ``lane_scale`` (exactly 1 on a straight road, so there every product below is the
straight road's number to the bit).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.config import EnvConfig
from jaxlc.sim import gap, kinematics
from jaxlc.sim.state import CRUISE, Ego, EnvParams, EnvState


def road_curvature(state: EnvState, p: EnvParams) -> Array:
    """``()`` curvature of the road in ``state``: the episode's draw, or the constant."""
    return jnp.asarray(p.curvature if state.curvature is None else state.curvature)


def reference_y(p: EnvParams) -> Array:
    """y of the road's centre line, the reference line of the Frenet frame."""
    return 0.5 * p.lanes * p.lane_width


def origin_lane(p: EnvParams | EnvConfig) -> int:
    """The lane every ego starts on and leaves (static: ``lanes`` fixes shapes)."""
    return p.lanes // 2


def origin_y(p: EnvParams) -> Array:
    """``()`` float32 y of the origin lane's centre line, where every ego starts.

    Rounded to float32 before any use: the ego's y is set from it and the offset from the
    target lane subtracts it, so a manoeuvre starts exactly one lane width from its target
    (``border >= lane_width`` keeps that in bounds). Without the barrier, params passed traced
    let XLA fuse the product into the subtraction (an FMA, unrounded) while the stored y was
    rounded, and the start could land a rounding step past the border."""
    return jax.lax.optimization_barrier(
        jnp.asarray((origin_lane(p) + 0.5) * p.lane_width, jnp.float32)
    )


def lane_offset(lane: Array, p: EnvParams) -> Array:
    """Signed offset d of lane ``lane``'s centre line from the reference line (any shape)."""
    return (lane + 0.5) * p.lane_width - reference_y(p)


def lane_scales(kappa: Array, p: EnvParams) -> Array:
    """``(lanes,)`` metres along each lane's centre line per metre of s."""
    return kinematics.lane_scale(kappa, lane_offset(jnp.arange(p.lanes), p))


def lane_row(a: Array, lane: Array, lanes: int) -> Array:
    """``a[lane]`` for a traced lane index, as a masked sum (cheaper than a gather under vmap)."""
    sel = (jnp.arange(lanes) == lane)[:, None]
    if a.dtype == jnp.bool_:
        return jnp.any(sel & a, axis=0)
    return jnp.sum(jnp.where(sel, a, 0), axis=0)


def current_lane(eg: Ego, p: EnvParams) -> Array:
    """Index of the lane that holds the ego's centre (the origin lane until it crosses)."""
    return jnp.clip(jnp.floor(eg.y / p.lane_width), 0, p.lanes - 1).astype(jnp.int32)


def ego_lanes(ego: Ego, p: EnvParams) -> Array:
    """``(lanes,)`` bool, lanes the ego's body overlaps (none while no ego is on the road)."""
    _, hy = kinematics.half_extents(ego.psi, p.vehicle_length, p.vehicle_width)
    return kinematics.lanes_overlapped(ego.y, hy, p.lanes, p.lane_width) & (ego.phase >= CRUISE)


def body_in_lane(ego: Ego, lane: Array, p: EnvParams) -> Array:
    """``(...)`` bool: the ego's body reaches into lane ``lane`` (any batch shape; whatever
    the ego's phase)."""
    _, hy = kinematics.half_extents(ego.psi, p.vehicle_length, p.vehicle_width)
    touched = kinematics.lanes_overlapped(ego.y, hy, p.lanes, p.lane_width)
    return jnp.any(touched & (jnp.arange(p.lanes) == jnp.asarray(lane)[..., None]), axis=-1)


def lateral_offset(eg: Ego, p: EnvParams) -> Array:
    """Signed offset of the ego from the target lane's centre line, m.

    Measured from the origin lane's centre (``origin_y``) so that it is exactly +-W when the
    manoeuvre starts (``5.55 - 1.85`` rounds above 3.7 in float32 and would end it at once)."""
    return (eg.y - origin_y(p)) - (eg.target - origin_lane(p)) * p.lane_width


def ego_yaw_rate(eg: Ego, kappa: Array, p: EnvParams) -> Array:
    """``()`` the ego's yaw rate relative to its lane's (``kinematics.relative_yaw_rate``): what
    the success test and the reward's comfort term read; ``eg.omega`` on a straight road."""
    return kinematics.relative_yaw_rate(eg.omega, eg.psi, eg.v, kappa, eg.y - reference_y(p))


def lane_keeping_yaw_rate(eg: Ego, v: Array, kappa: Array, p: EnvParams) -> Array:
    """``()`` the yaw rate that holds the ego's line at speed ``v`` (psi = 0): kappa_d*v."""
    return kinematics.path_curvature(kappa, eg.y - reference_y(p)) * v


def target_frame(nb: gap.Neighbours, eg: Ego, kappa: Array, p: EnvParams):
    """``(nb, x)``: the target lane's neighbours and the ego's x in metres along the target
    lane's centre line (``gap``'s functions measure gaps in these)."""
    c = kinematics.lane_scale(kappa, lane_offset(eg.target, p))
    return gap.scaled(nb, c), eg.x * c
