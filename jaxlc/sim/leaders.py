"""Who is where in a traffic that changes lanes: the lanes each body counts in, its lateral
position, and every vehicle's leader and follower in every lane, found by position.

With ``env.mobil`` a slot's row is the lane its vehicle entered, not the lane it drives in, so
a vehicle's leader is no longer the slot written before it (``traffic.ring_leaders``). Here
every vehicle of an env, the ego included, is one entry of a flat list of ``V = lanes * slots
+ 1`` (the ego last), sorted by position once per step; for each vehicle ``i`` and lane ``l``
the nearest vehicle ahead and behind that counts in ``l`` is the nearest rank after and
before ``i``'s among those counting in ``l``. A vehicle changing lanes counts in both lanes
until its lane change ends.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import gap, kinematics
from jaxlc.sim.idm import NO_LEADER_GAP
from jaxlc.sim.road import current_lane, ego_lanes
from jaxlc.sim.state import Ego, EnvParams, Traffic


def changing(tr: Traffic) -> Array:
    """``(lanes, slots)`` bool: the vehicle is in a lane change (needs ``env.mobil``)."""
    return tr.active & (tr.lc_time < tr.lc_dur)


def occupancy(tr: Traffic, p: EnvParams) -> Array:
    """``(lanes, rows, slots)`` bool: entry ``[l]`` marks the vehicles whose body counts in lane
    ``l``: the lane it drives in and, during a lane change, the lane it leaves. Without
    ``env.mobil`` a row is its lane."""
    ids = jnp.arange(p.lanes)[:, None, None]
    if tr.lane is None:
        return (ids == jnp.arange(p.lanes)[None, :, None]) & tr.active[None]
    leaving = changing(tr)[None] & (tr.lane_from[None] == ids)
    return tr.active[None] & ((tr.lane[None] == ids) | leaving)


def profile(tau: Array) -> Array:
    """The lane change's smooth lateral profile, 0 -> 1 over ``tau`` in [0, 1] (the quintic
    of least jerk: zero lateral speed and acceleration at both ends)."""
    t = jnp.clip(tau, 0.0, 1.0)
    return t * t * t * (10.0 + t * (-15.0 + 6.0 * t))


def vehicle_y(tr: Traffic, p: EnvParams) -> Array:
    """``(rows, slots)`` lateral position of each body's centre line, m (lane ``l`` spans
    ``[l*W, (l+1)*W]``); a vehicle changing lanes moves along ``profile``."""
    if tr.lane is None:
        return jnp.broadcast_to((jnp.arange(p.lanes)[:, None] + 0.5) * p.lane_width, tr.x.shape)
    frac = profile(tr.lc_time / jnp.maximum(tr.lc_dur, 1e-6))
    frac = jnp.where(tr.lc_time < tr.lc_dur, frac, 1.0)
    return (tr.lane_from + 0.5 + (tr.lane - tr.lane_from) * frac) * p.lane_width


class Around(NamedTuple):
    """Every vehicle of one env (flat, the ego last: ``V = lanes * slots + 1``) and, per lane,
    its nearest vehicle ahead (lead) and behind (lag) that counts in that lane."""

    x: Array  # (V,) front bumper, s along the road's centre line, m
    v: Array  # (V,) speed, m/s
    v0: Array  # (V,) desired speed, m/s
    length: Array  # (V,) body length along the road, m (the ego's heading-aligned box)
    occ: Array  # (lanes, V) bool, the lanes each body counts in
    lead: Array  # (lanes, V) int32 index of the lead in that lane (any value where none)
    has_lead: Array  # (lanes, V) bool
    lag: Array  # (lanes, V) int32 index of the lag in that lane
    has_lag: Array  # (lanes, V) bool
    scale: Array  # (lanes,) m along each lane per m of s


def around(tr: Traffic, eg: Ego, p: EnvParams, scale: Array) -> Around:
    """Leaders and followers of every vehicle in every lane, the ego counted where its body
    is (``road.ego_lanes``) while it is on the road. ``scale`` ``(lanes,)``: ``lane_scales``.

    One sort of the env's vehicles by position (``_order``), then per lane the nearest
    vehicle counting in it before and after each rank (prefix scans): ``O(V log V)`` per env
    where comparing every pair costs ``lanes * V**2``."""
    hx, _ = kinematics.half_extents(eg.psi, p.vehicle_length, p.vehicle_width)
    x = jnp.append(tr.x.reshape(-1), eg.x)
    v = jnp.append(tr.v.reshape(-1), eg.v)
    v0 = jnp.append(tr.v0.reshape(-1), eg.v0)
    length = jnp.append(jnp.full(tr.x.size, p.vehicle_length, x.dtype), 2.0 * hx)
    occ = jnp.concatenate(
        [occupancy(tr, p).reshape(p.lanes, -1), ego_lanes(eg, p)[:, None]], axis=1
    )
    n = x.shape[0]
    bits = max(1, (n - 1).bit_length())  # static: an index in the key's low bits
    ids = _order(x, p.road_length, bits)  # (V,) int32 the vehicle at each rank
    # Per lane and rank, "rank << bits | id" of a vehicle counting in that lane, else a
    # sentinel: the nearest one after a rank is the smallest code after it.
    code = jnp.arange(n, dtype=jnp.int32) * (1 << bits) + ids  # (V,)
    in_lane = occ[:, ids]  # (lanes, V) by rank
    none_ahead, none_behind = jnp.int32(_BIG), jnp.int32(-1)
    ahead = _shift(jnp.where(in_lane, code, none_ahead), 1, none_ahead)
    behind = _shift(jnp.where(in_lane, code, none_behind), -1, none_behind)
    nxt = _scan(ahead, jnp.minimum, 1, none_ahead)
    prv = _scan(behind, jnp.maximum, -1, none_behind)
    # Back in slot order by a scatter, not a gather: XLA's CPU fusion would pull the scans
    # into every reader of a gather and redo them per element read.
    nxt, prv = (jnp.zeros_like(c).at[:, ids].set(c, unique_indices=True) for c in (nxt, prv))
    mask = (1 << bits) - 1
    return Around(
        x=x,
        v=v,
        v0=v0,
        length=length,
        occ=occ,
        lead=nxt & mask,
        has_lead=nxt != none_ahead,
        lag=jnp.maximum(prv, 0) & mask,
        has_lag=prv != none_behind,
        scale=scale,
    )


_BIG = 2**31 - 1


def _order(x: Array, road_length: Array, bits: int) -> Array:
    """``(V,)`` int32: the vehicles by position, ties by index (``ids[r]`` is at rank ``r``).
    Positions are keyed to ``2 * road_length / 2**(31 - bits)`` m levels, within float32's
    rounding of the level (1.4e-4 m on 600 m with 49 vehicles), far below a body's length, in
    one int32 with the index: XLA sorts one int32 operand several times faster than a float
    key with an index beside it."""
    levels = 2 ** (31 - bits)
    q = jnp.floor((x + 0.5 * road_length) * (levels / (2.0 * road_length)))
    q = jnp.clip(q, 0, levels - 1).astype(jnp.int32)
    return jnp.sort(q * (1 << bits) + jnp.arange(x.shape[0], dtype=jnp.int32)) & ((1 << bits) - 1)


def _shift(a: Array, by: int, fill: Array) -> Array:
    """``a`` moved ``by`` places along its last axis (``+1``: entry ``r`` takes ``r + 1``'s),
    ``fill`` where nothing moves in."""
    pad = jnp.full(a.shape[:-1] + (abs(by),), fill, a.dtype)
    return jnp.concatenate([a[..., by:], pad] if by > 0 else [pad, a[..., :by]], axis=-1)


def _scan(a: Array, op, direction: int, identity: Array) -> Array:
    """Inclusive scan of ``op`` along the last axis, from the end (``direction=1``) or the
    start (``-1``), by doubling: ``log2(V)`` elementwise steps (``lax.cummin`` lowers to a
    slower loop on the CPU)."""
    k = 1
    while k < a.shape[-1]:
        a = op(a, _shift(a, direction * k, identity))
        k *= 2
    return a


def net_gap(a: Around, back: Array, front: Array, present: Array) -> Array:
    """``(lanes, V)`` net gap, m along each lane, from vehicle ``back`` to ``front`` (index
    arrays of that shape); ``NO_LEADER_GAP`` where not ``present``."""
    c = a.scale[:, None]
    g = a.x[front] * c - a.length[front] - a.x[back] * c
    return jnp.where(present, g, NO_LEADER_GAP)


def ego_neighbours(tr: Traffic, eg: Ego, p: EnvParams) -> Array:
    """``(rows, slots)`` bool: the vehicles around the ego whose headway and time-to-collision
    the evaluation measures (any of ``ego_neighbour_roles``)."""
    return jnp.any(ego_neighbour_roles(tr, eg, p), axis=0)


def ego_neighbour_roles(tr: Traffic, eg: Ego, p: EnvParams) -> Array:
    """``(3, rows, slots)`` bool: the ego's lead and lag in its target lane and the leader in
    the lane that holds its centre (a body counts in every lane of ``occupancy``)."""
    occ = occupancy(tr, p)
    lanes = jnp.arange(p.lanes)[:, None, None]
    in_target = jnp.any(occ & (lanes == eg.target), axis=0)
    in_own = jnp.any(occ & (lanes == current_lane(eg, p)), axis=0)
    ahead = tr.x > eg.x

    def nearest(mask: Array, pick) -> Array:
        far = gap.FAR if pick is jnp.min else -gap.FAR
        return mask & (tr.x == pick(jnp.where(mask, tr.x, far)))

    return jnp.stack(
        [
            nearest(in_target & ahead, jnp.min),
            nearest(in_target & ~ahead, jnp.max),
            nearest(in_own & ahead, jnp.min),
        ]
    )
