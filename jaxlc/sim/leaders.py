"""Who is where in a traffic that changes lanes: the lanes each body counts in, its lateral
position, and every vehicle's leader and follower in every lane, found by position.

With ``env.mobil`` a slot's row is the lane its vehicle entered, not the lane it drives in, so
a vehicle's leader is no longer the slot written before it (``traffic.ring_leaders``). Here
every vehicle of an env, the ego included, is one entry of a flat list of ``V = lanes * slots
+ 1`` (the ego last); for each vehicle ``i`` and lane ``l`` the nearest vehicle ahead and
behind that counts in ``l`` is found by comparing ``i`` with every other. A vehicle changing
lanes counts in both lanes until its lane change ends.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.sim import gap, kinematics
from jaxlc.sim.idm import free_road
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
    its nearest vehicle ahead (lead) that counts in that lane; ``lags`` finds the nearest
    behind for the few vehicles that need it."""

    x: Array  # (V,) front bumper, s along the road's centre line, m
    v: Array  # (V,) speed, m/s
    v0: Array  # (V,) desired speed, m/s
    free: Array  # (V,) the IDM's free-road term (``idm.free_road``), once per body
    length: Array  # (V,) body length along the road, m (the ego's heading-aligned box)
    occ: Array  # (lanes, V) bool, the lanes each body counts in
    key: Array  # (V,) int32 position key (``_keys``): the bodies' order along the road
    lead: Array  # (lanes, V) int32 index of the lead in that lane (any value where none)
    has_lead: Array  # (lanes, V) bool
    scale: Array  # (lanes,) m along each lane per m of s


def around(tr: Traffic, eg: Ego, p: EnvParams, scale: Array) -> Around:
    """Leaders of every vehicle in every lane, the ego counted where its body is
    (``road.ego_lanes``) while it is on the road. ``scale`` ``(lanes,)``: ``lane_scales``.

    Each body gets one int32 key, its position level and its index (``_keys``); the lead of
    ``i`` in lane ``l`` is the body counting in ``l`` with the least key above ``i``'s, and
    the key's low bits are that body's index (``_nearest``)."""
    hx, _ = kinematics.half_extents(eg.psi, p.vehicle_length, p.vehicle_width)
    x = jnp.append(tr.x.reshape(-1), eg.x)
    occ = jnp.concatenate(
        [occupancy(tr, p).reshape(p.lanes, -1), ego_lanes(eg, p)[:, None]], axis=1
    )
    key = _keys(x, p.road_length)
    lead, has_lead = _index(_nearest(key, occ, key, ahead=True), x.shape[0])
    v, v0 = jnp.append(tr.v.reshape(-1), eg.v), jnp.append(tr.v0.reshape(-1), eg.v0)
    return Around(
        x=x,
        v=v,
        v0=v0,
        free=free_road(v, v0, p.idm_delta),
        length=jnp.append(jnp.full(tr.x.size, p.vehicle_length, x.dtype), 2.0 * hx),
        occ=occ,
        key=key,
        lead=lead,
        has_lead=has_lead,
        scale=scale,
    )


def lags(a: Around, cols: Array) -> tuple[Array, Array]:
    """``(lag, has_lag)``, ``(lanes, K)`` each: per lane, the index of the nearest vehicle
    behind each of ``cols`` ``(K,)`` that counts in the lane (any value where none)."""
    return _index(_nearest(a.key, a.occ, a.key[cols], ahead=False), a.x.shape[0])


_NONE_ABOVE = jnp.iinfo(jnp.int32).max  # no key is this high: no lead
_NONE_BELOW = -1  # every key is >= 0: no lag


def _bits(n: int) -> int:
    """Low bits of a key that hold the index of one of ``n`` bodies."""
    return max(1, (n - 1).bit_length())


def _keys(x: Array, road_length: Array) -> Array:
    """``(V,)`` int32, unique, ordered as the bodies' positions, ties by index: the position's
    level of ``2 * road_length / 2**(31 - bits)`` m (1.4e-4 m on 600 m with 49 bodies, within
    float32's rounding of it) times ``2**bits``, plus the index. Levels are clipped below the
    top one, which float32 rounds up to ``2**(31 - bits)`` (an int32 overflow for a body past
    ``1.5 * road_length``), so every key is >= 0 and below ``_NONE_ABOVE``."""
    bits = _bits(x.shape[0])
    levels = 2 ** (31 - bits)
    q = jnp.floor((x + 0.5 * road_length) * (levels / (2.0 * road_length)))
    q = jnp.clip(q, 0, levels - 2).astype(jnp.int32)
    return q * (1 << bits) + jnp.arange(x.shape[0], dtype=jnp.int32)


def _index(found: Array, n: int) -> tuple[Array, Array]:
    """``(index, present)`` of the bodies whose keys ``_nearest`` found (``n - 1`` where
    none)."""
    present = (found != _NONE_ABOVE) & (found != _NONE_BELOW)
    return jnp.where(present, found & ((1 << _bits(n)) - 1), n - 1), present


def _nearest(key: Array, occ: Array, subject: Array, ahead: bool) -> Array:
    """``(lanes, S)`` int32: per lane, among the bodies counting in it, the least key above
    each of ``subject`` ``(S,)`` (``ahead``; ``_NONE_ABOVE`` where none) or the greatest below
    it (``_NONE_BELOW``). ``key`` ``(V,)``, ``occ`` ``(lanes, V)``.

    Every body compared with every subject, as a loop over the body of elementwise passes over
    ``(lanes, S)``: under ``vmap`` each pass is elementwise over the batch, which XLA's CPU runs
    several times faster than a sort of the bodies (a bitonic network of the 49 keys alone
    cost more than this whole search) or a reduction over a pair axis. A pass is one
    subtraction and one min: the distance ``key - (subject + 1)`` (ahead; ``(subject - 1) -
    key`` behind) taken as uint32 is small for a key on the wanted side and wraps past 2**31
    for the others, and a body not in the lane has the key ``none``, whose distance is that of
    the answer "none". Unrolled by the largest divisor of ``V`` up to 8 (7 for 49 bodies): a
    remainder loop, or no unrolling, ran the hazard traffic 17-32% slower, a full unroll 3x
    slower."""
    none = _NONE_ABOVE if ahead else _NONE_BELOW
    u32 = lambda a: jax.lax.bitcast_convert_type(a, jnp.uint32)  # noqa: E731
    masked = u32(jnp.where(occ, key[None, :], none))  # (lanes, V)
    edge = u32(subject + 1 if ahead else subject - 1)[None, :]  # (1, S)

    def distance(k: Array) -> Array:  # uint32, of key k from each subject
        return k - edge if ahead else edge - k

    def body(j: Array, found: Array) -> Array:
        return jnp.minimum(found, distance(masked[:, j][:, None]))

    init = jnp.broadcast_to(distance(u32(jnp.int32(none))), (occ.shape[0], subject.shape[0]))
    n = key.shape[0]
    unroll = max(d for d in range(1, 9) if n % d == 0)
    d = jax.lax.fori_loop(0, n, body, init, unroll=unroll)
    return jax.lax.bitcast_convert_type(d + edge if ahead else edge - d, jnp.int32)


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
