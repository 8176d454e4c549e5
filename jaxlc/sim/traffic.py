"""The traffic: its own part of the env's step (``step``: every vehicle's acceleration and
move, the lane changes, the inflow at x = 0, the braking events, in that order), its draws
(``step_draws``) and an empty road's traffic (``empty``); who follows whom, every vehicle's IDM
acceleration, and the inflow.

In the paper's traffic only the ego changes lanes, so vehicles of a lane never pass each other
and a vehicle's leader is simply the slot written before it in its lane's ring buffer: no
search (``ring_leaders``). With ``env.mobil`` the other vehicles change lanes too, and every
leader is found by position in each lane the vehicle counts in (``leaders.around``); with
``env.braking`` a braking event lowers a vehicle's acceleration (``braking.braked``).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import braking, gap, kinematics, leaders, mobil
from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params
from jaxlc.sim.leaders import Around, occupancy
from jaxlc.sim.motion import Motion, move
from jaxlc.sim.road import ego_lanes, lane_scales, origin_lane, road_curvature
from jaxlc.sim.state import (
    CRUISE,
    RL,
    Draws,
    EnvParams,
    EnvState,
    Traffic,
    TrafficDraws,
    between,
)


def ring_leaders(tr: Traffic, p: EnvParams, scale: Array) -> tuple[Array, Array]:
    """Net gap and speed of each slot's leader: the slot written just before it, when that
    slot is occupied and ahead (a full ring's oldest slot has the newest behind it). ``scale``
    ``(lanes,)`` is ``lane_scales``: the gap is metres along the lane."""
    px, pv, pa = (jnp.roll(a, 1, axis=-1) for a in (tr.x, tr.v, tr.active))
    has = pa & (px > tr.x)
    c = scale[:, None]
    gap_m = px * c - p.vehicle_length - tr.x * c
    return jnp.where(has, gap_m, NO_LEADER_GAP), jnp.where(has, pv, tr.v)


def traffic_accel(state: EnvState, p: EnvParams, a: Around | None = None) -> Array:
    """``(lanes, slots)`` IDM acceleration of every vehicle (0 for empty slots).

    A vehicle's leader is its ring predecessor, or the ego when the ego is ahead and its body
    overlaps the vehicle's lane (or, for a yielding lag, from the moment the gap is chosen).
    Gaps are metres along the vehicle's lane. With ``env.mobil`` (``a``: the state's
    ``leaders.around``) the leaders are found by position, in each lane the vehicle counts in,
    and the lowest of those accelerations is taken; a braking event (``env.braking``) lowers
    it further."""
    tr = state.traffic
    acc = _ring_accel(state, p) if a is None else _position_accel(state, a, p)
    return acc if tr.brake_left is None else braking.braked(acc, tr)


def _position_accel(state: EnvState, a: Around, p: EnvParams) -> Array:
    tr, eg, nb = state.traffic, state.ego, state.nb
    n = tr.x.size
    subject = jnp.broadcast_to(jnp.arange(a.x.shape[0]), a.lead.shape)  # (lanes, V)
    c = a.scale[:, None]
    gap_l = jnp.where(
        a.has_lead, a.x[a.lead] * c - a.length[a.lead] - a.x[subject] * c, NO_LEADER_GAP
    )
    lead_v = jnp.where(a.has_lead, a.v[a.lead], a.v)
    # The yielding lag takes the ego as its leader from the gap's acceptance, before the
    # ego's body is in its lane (SPEC, "yield or overpass").
    hx, _ = kinematics.half_extents(eg.psi, p.vehicle_length, p.vehicle_width)
    ego_gap = (eg.x * c - 2.0 * hx - a.x * c)[:, :n]  # (lanes, N)
    yields = (eg.phase == RL) & eg.yielding & nb.b1_mask.reshape(-1)  # (N,)
    yields = (jnp.arange(p.lanes) == eg.target)[:, None] & yields[None, :]
    use_ego = yields & (eg.x > a.x[:n]) & (ego_gap < gap_l[:, :n])
    gap_l = jnp.where(use_ego, ego_gap, gap_l[:, :n])
    lead_v = jnp.where(use_ego, eg.v, lead_v[:, :n])
    acc = idm_with_params(a.v[:n], a.v0[:n], gap_l, lead_v, p, a.free[:n])  # (lanes, N)
    acc = jnp.min(jnp.where(a.occ[:, :n], acc, jnp.inf), axis=0).reshape(tr.x.shape)
    return jnp.where(tr.active, acc, 0.0)


def _ring_accel(state: EnvState, p: EnvParams) -> Array:
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
    lanes, slots, origin = p.lanes, p.slots_per_lane, origin_lane(p)
    lane_ids, slot_ids = jnp.arange(lanes), jnp.arange(slots)
    if tr.lane is None:
        at_tail = slot_ids[None, :] == tr.tail[:, None]
        at_last = slot_ids[None, :] == ((tr.tail - 1) % slots)[:, None]
        last_on = jnp.any(at_last & m.active, axis=-1)
        front = jnp.where(last_on, jnp.sum(jnp.where(at_last, m.x, 0.0), axis=-1), gap.FAR)
        room = ~jnp.any(at_tail & m.active, axis=-1)
    else:  # rows are not lanes: the rearmost body in the lane; an entrant takes a free slot
        occ = occupancy(tr.replace(x=m.x, active=m.active), p).reshape(lanes, -1)
        front = jnp.min(jnp.where(occ, m.x.reshape(-1)[None, :], gap.FAR), axis=-1)
        # The first free slot of each row (``slots`` where none), by a min: a cumsum or an
        # argmax over the row cost XLA's CPU several times more.
        first = jnp.min(jnp.where(m.active, slots, slot_ids), axis=-1)  # (lanes,)
        at_tail = slot_ids[None, :] == first[:, None]
        room = first < slots
    front = jnp.where(occupied, jnp.minimum(front, m.ego_x), front)
    front = front * lane_scales(p.curvature if kappa is None else kappa, p)  # m along the lane
    timer = tr.timer - p.dt
    due = (timer <= 0.0) & (front >= p.idm_s0 + tr.next_v * p.idm_time_headway + p.vehicle_length)
    spawned_lane = due & (lane_ids == origin) & can_spawn
    enter = due & ~spawned_lane & room
    entered = enter | spawned_lane
    write = at_tail & enter[:, None]
    spawned = spawned_lane[origin]
    traffic = tr.replace(
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
    if tr.lane is not None:  # an entrant drives in its row's lane and has changed none
        row = jnp.broadcast_to(lane_ids[:, None], write.shape)
        traffic = traffic.replace(
            tail=jnp.where(enter, first, tr.tail).astype(jnp.int32),
            lane=jnp.where(write, row, tr.lane),
            lane_from=jnp.where(write, row, tr.lane_from),
            lc_time=jnp.where(write, mobil.NEVER, tr.lc_time),
            lc_dur=jnp.where(write, 0.0, tr.lc_dur),
        )
    if tr.brake_left is not None:
        traffic = traffic.replace(brake_left=jnp.where(write, 0.0, tr.brake_left))
    return traffic, spawned


def empty(u: Array, p: EnvParams) -> Traffic:
    """An empty road's traffic; ``u`` ``(4, lanes)`` uniform numbers: the first entries'
    timers, speeds and desired speeds, and the lanes' inflow."""
    lanes, slots = p.lanes, p.slots_per_lane
    zeros = jnp.zeros((lanes, slots), jnp.float32)
    inflow = between(u[3], p.inflow_min, p.inflow_max)
    traffic = Traffic(
        x=zeros,
        v=zeros,
        v0=zeros + p.desired_speed_max,
        active=jnp.zeros((lanes, slots), bool),
        tail=jnp.zeros(lanes, jnp.int32),
        timer=-jnp.log1p(-u[0]) / inflow,
        next_v=between(u[1], p.entry_speed_min, p.entry_speed_max),
        next_v0=between(u[2], p.desired_speed_min, p.desired_speed_max),
        inflow=inflow,
    )
    if p.mobil:
        rows = jnp.broadcast_to(jnp.arange(lanes, dtype=jnp.int32)[:, None], (lanes, slots))
        traffic = traffic.replace(
            lane=rows, lane_from=rows, lc_time=zeros + mobil.NEVER, lc_dur=zeros
        )
    if p.braking:
        traffic = traffic.replace(brake_left=zeros, brake_acc=zeros)
    return traffic


class TrafficStep(NamedTuple):
    """The traffic's part of one step (``step``)."""

    motion: Motion  # every vehicle, the ego included, one dt on, before inflow
    before_inflow: Traffic  # after the lane changes' start, before inflow (an entrant's speeds)
    traffic: Traffic  # the traffic after the step
    spawned: Array  # () bool: the origin lane's entrant became the ego
    around: leaders.Around | None  # with env.mobil: leaders by position, before the move
    lane_changes: mobil.Decision | None  # with env.mobil
    events: braking.Events | None  # with env.braking


def step_draws(
    key: Array, p: EnvParams, state: EnvState | None = None
) -> tuple[Draws, TrafficDraws | None]:
    """The step's ``(Draws, TrafficDraws)`` from ``key``: the traffic's own, or, with a source
    ``p.draws`` and the ``state`` they are drawn in, that source's; no ``TrafficDraws`` (None)
    in the paper's traffic, which draws and computes none of them."""
    if p.draws is not None and state is not None:
        return p.draws.draw(key, state, p)
    u = Draws.draw(key, p.lanes)
    ut = TrafficDraws.draw(key, p.lanes, p.slots_per_lane) if p.mobil or p.braking else None
    return u, ut


def step(
    state: EnvState,
    u: Draws,
    ut: TrafficDraws | None,
    a_ego: Array,
    a_lat: Array,
    can_spawn: Array,
    p: EnvParams,
    kappa: Array,
) -> TrafficStep:
    """Every vehicle's acceleration and move, the lane changes (env.mobil), inflow and the
    braking events (env.braking); the ego moves by ``a_ego`` and ``a_lat``."""
    tr, eg = state.traffic, state.ego
    around = leaders.around(tr, eg, p, lane_scales(kappa, p)) if p.mobil else None
    m = move(tr, eg, traffic_accel(state, p, around), a_ego, a_lat, p, kappa)
    lc = events = None
    if p.mobil:  # lanes change before inflow, so an entrant sees who moved into its lane
        lc = mobil.decide(tr, around, ut, p)
        tr = mobil.advance(tr, m.active, lc, ut, p)
    traffic, spawned = inflow(tr, m, ego_lanes(eg, p), can_spawn, u, p, kappa)
    if p.braking:
        events = braking.advance(traffic, ut, p)
        traffic = events.traffic
    return TrafficStep(m, tr, traffic, spawned, around, lc, events)
