"""The traffic: who follows whom, every vehicle's IDM acceleration, and the inflow at x = 0.

Only the ego changes lanes, so vehicles of a lane never pass each other and a vehicle's leader
is simply the slot written before it in its lane's ring buffer: no search (``ring_leaders``).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import gap, kinematics
from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params
from jaxlc.sim.motion import Motion
from jaxlc.sim.road import ego_lanes, lane_scales, road_curvature
from jaxlc.sim.state import CRUISE, RL, Draws, EnvParams, EnvState, Traffic, between


def ring_leaders(tr: Traffic, p: EnvParams, scale: Array) -> tuple[Array, Array]:
    """Net gap and speed of each slot's leader: the slot written just before it, when that
    slot is occupied and ahead (a full ring's oldest slot has the newest behind it). ``scale``
    ``(lanes,)`` is ``lane_scales``: the gap is metres along the lane."""
    px, pv, pa = (jnp.roll(a, 1, axis=-1) for a in (tr.x, tr.v, tr.active))
    has = pa & (px > tr.x)
    c = scale[:, None]
    gap_m = px * c - p.vehicle_length - tr.x * c
    return jnp.where(has, gap_m, NO_LEADER_GAP), jnp.where(has, pv, tr.v)


def traffic_accel(state: EnvState, p: EnvParams) -> Array:
    """``(lanes, slots)`` IDM acceleration of every vehicle (0 for empty slots).

    A vehicle's leader is its ring predecessor, or the ego when the ego is ahead and its body
    overlaps the vehicle's lane (or, for a yielding lag, from the moment the gap is chosen).
    Gaps are metres along the vehicle's lane."""
    tr, eg, nb = state.traffic, state.ego, state.nb
    on, in_rl = eg.phase >= CRUISE, eg.phase == RL
    c = lane_scales(road_curvature(state, p), p)  # (lanes,)
    gap_r, lead_v = ring_leaders(tr, p, c)
    hx, _ = kinematics.half_extents(eg.psi, p.vehicle_length, p.vehicle_width)
    target = jnp.arange(p.lanes) == eg.target
    yields = (in_rl & eg.yielding) & target[:, None] & nb.b1_mask[None, :]
    ego_gap = eg.x * c[:, None] - 2.0 * hx - tr.x * c[:, None]  # (lanes, slots)
    use_ego = on & (eg.x > tr.x) & (ego_lanes(eg, p)[:, None] | yields) & (ego_gap < gap_r)
    gap_r = jnp.where(use_ego, ego_gap, gap_r)
    lead_v = jnp.where(use_ego, eg.v, lead_v)
    return jnp.where(tr.active, idm_with_params(tr.v, tr.v0, gap_r, lead_v, p), 0.0)


def inflow(
    tr: Traffic,
    m: Motion,
    occupied: Array,
    can_spawn: Array,
    u: Draws,
    p: EnvParams,
    kappa: Array | None = None,
) -> tuple[Traffic, Array]:
    """New vehicles at x = 0. Returns ``(traffic, spawned)``, ``spawned`` () bool.

    A lane admits its next vehicle when its timer has run out and the last entered vehicle
    (or the ego, if it is in that lane and further back) is far enough ahead. When
    ``can_spawn`` (no ego, spawning on), the middle lane's entrant becomes the ego instead of
    a slot, and the episode it starts draws the lanes' inflow anew."""
    lanes, slots, origin = p.lanes, p.slots_per_lane, p.lanes // 2
    lane_ids, slot_ids = jnp.arange(lanes), jnp.arange(slots)
    at_tail = slot_ids[None, :] == tr.tail[:, None]
    at_last = slot_ids[None, :] == ((tr.tail - 1) % slots)[:, None]
    last_on = jnp.any(at_last & m.active, axis=-1)
    front = jnp.where(last_on, jnp.sum(jnp.where(at_last, m.x, 0.0), axis=-1), gap.FAR)
    front = jnp.where(occupied, jnp.minimum(front, m.ego_x), front)
    front = front * lane_scales(p.curvature if kappa is None else kappa, p)  # m along the lane
    timer = tr.timer - p.dt
    due = (timer <= 0.0) & (front >= p.idm_s0 + tr.next_v * p.idm_time_headway + p.vehicle_length)
    spawned_lane = due & (lane_ids == origin) & can_spawn
    enter = due & ~spawned_lane & ~jnp.any(at_tail & m.active, axis=-1)
    entered = enter | spawned_lane
    write = at_tail & enter[:, None]
    spawned = spawned_lane[origin]
    traffic = Traffic(
        x=jnp.where(write, 0.0, m.x),
        v=jnp.where(write, tr.next_v[:, None], m.v),
        v0=jnp.where(write, tr.next_v0[:, None], tr.v0),
        active=m.active | write,
        tail=(tr.tail + enter) % slots,
        timer=jnp.where(entered, -jnp.log1p(-u.headway) / tr.inflow, timer),
        next_v=jnp.where(
            entered, between(u.entry_v, p.entry_speed_min, p.entry_speed_max), tr.next_v
        ),
        next_v0=jnp.where(
            entered, between(u.entry_v0, p.desired_speed_min, p.desired_speed_max), tr.next_v0
        ),
        inflow=jnp.where(spawned, between(u.inflow, p.inflow_min, p.inflow_max), tr.inflow),
    )
    return traffic, spawned
