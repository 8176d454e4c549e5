"""Lane changes of the other vehicles: MOBIL (Kesting, Treiber & Helbing 2007) on the IDM.

A vehicle ``c`` that is not changing lanes, and whose last lane change started at least
``mobil_interval`` s ago, may move one lane toward ``d`` (+1 left, -1 right) when

    incentive:  ã_c - a_c + p * (ã_n - a_n + ã_o - a_o) > Δa_th - d * bias
    safety:     ã_n >= -b_safe and ã_c >= -b_safe, and both net gaps >= s0

with ``a`` the IDM accelerations now and ``ã`` after the change, ``n`` the new follower (in
the target lane) and ``o`` the old one; p ``mobil_politeness``, Δa_th ``mobil_threshold``,
bias ``mobil_bias_right``, b_safe the ego's gap test's ``b_safe``. The ego is a vehicle to it
(``leaders.around`` counts it where its body is), so a vehicle moves into the ego's gap or
ahead of it in its lane only where the ego's own braking would stay within b_safe. Of the two
sides the larger incentive is taken. A driver acts on an allowed change at ``mobil_rate`` per
second (the step's draw ``lc_fire``); of two drivers starting toward the same lane within a
safe distance of each other on one step, the one in the lower slot goes, and of an env's
drivers acting on one step the first ``STARTERS`` in slot order may start (the others act
again on a later step's draw). The change lasts a drawn ``U(lane_change_time_min, _max)`` s
along ``leaders.profile``; meanwhile the body counts in both lanes (``leaders.occupancy``): it
leads and follows in each.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.sim.gap import FAR
from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params
from jaxlc.sim.leaders import Around, changing
from jaxlc.sim.road import current_lane
from jaxlc.sim.state import GAP, Ego, EnvParams, Traffic, TrafficDraws, between

NEVER = 1e4  # s since the last lane change of a vehicle that has made none
STARTERS = 8  # static: the most drivers of one env that start a lane change on one step


class Decision(NamedTuple):
    """One step's lane-change decisions, ``(lanes, slots)`` each (slot order)."""

    allowed: Array  # bool: eligible, and MOBIL allows a change to one side
    fired: Array  # bool: allowed, and the driver acts this step
    start: Array  # bool: fired and not held back by a nearer starter
    to: Array  # int32 the lane it moves to where allowed, else -1


def _idm(a: Around, f: Array, lead: Array, present: Array, lane: Array, p: EnvParams):
    """``(acc, gap)`` of vehicles ``f`` following ``lead`` (where ``present``) in ``lane``."""
    c = a.scale[lane]
    g = jnp.where(present, a.x[lead] * c - a.length[lead] - a.x[f] * c, NO_LEADER_GAP)
    v_lead = jnp.where(present, a.v[lead], a.v[f])
    return idm_with_params(a.v[f], a.v0[f], g, v_lead, p), g


def _in_lane(table: Array, lane: Array, n: int) -> Array:
    """``table[lane[i], i]`` for the first ``n`` vehicles (``table``: ``(lanes, V)``), by a
    one-hot over the few lanes: a gather's index array costs XLA's CPU more than the pick."""
    pick = lane[None, :] == jnp.arange(table.shape[0])[:, None]  # (lanes, n)
    if table.dtype == jnp.bool_:
        return jnp.any(pick & table[:, :n], axis=0)
    return jnp.sum(jnp.where(pick, table[:, :n], 0), axis=0, dtype=table.dtype)


def _lead_lag(a: Around, lane: Array, n: int) -> tuple[Array, Array, Array, Array]:
    """``(lead, has_lead, lag, has_lag)`` of the first ``n`` vehicles in lanes ``lane`` ``(n,)``."""
    return tuple(_in_lane(t, lane, n) for t in (a.lead, a.has_lead, a.lag, a.has_lag))


def decide(tr: Traffic, a: Around, u: TrafficDraws, p: EnvParams) -> Decision:
    """Which vehicles start a lane change on this step, and to which lane (``a``: the state's
    ``leaders.around``; positions are those of the state before the step's move)."""
    n = tr.x.size
    i = jnp.arange(n)
    lane = tr.lane.reshape(-1)
    cur_lead, has_cur, old, has_old = _lead_lag(a, lane, n)
    a_c, _ = _idm(a, i, cur_lead, has_cur, lane, p)
    a_o, _ = _idm(a, old, i, True, lane, p)
    at_o, _ = _idm(a, old, cur_lead, has_cur, lane, p)
    gain_o = jnp.where(has_old, at_o - a_o, 0.0)

    def side(d: int) -> tuple[Array, Array, Array]:
        to = lane + d
        ok = (to >= 0) & (to < p.lanes)
        to = jnp.clip(to, 0, p.lanes - 1)
        lead, has_lead, new, has_new = _lead_lag(a, to, n)
        at_c, front = _idm(a, i, lead, has_lead, to, p)
        a_n, _ = _idm(a, new, lead, has_lead, to, p)
        at_n, back = _idm(a, new, i, True, to, p)
        gain_n = jnp.where(has_new, at_n - a_n, 0.0)
        incentive = at_c - a_c + p.mobil_politeness * (gain_n + gain_o)
        incentive = incentive - p.mobil_threshold - d * p.mobil_bias_right
        safe = (at_c >= -p.b_safe) & (front >= p.idm_s0)
        safe &= ~has_new | ((at_n >= -p.b_safe) & (back >= p.idm_s0))
        return ok & safe & (incentive > 0.0), incentive, to

    left_ok, left_gain, left_to = side(1)
    right_ok, right_gain, right_to = side(-1)
    go_left = left_ok & (~right_ok | (left_gain >= right_gain))
    to = jnp.where(go_left, left_to, right_to).astype(jnp.int32)
    eligible = tr.active.reshape(-1) & ~changing(tr).reshape(-1)
    eligible &= tr.lc_time.reshape(-1) >= p.mobil_interval
    # Each allowed driver's new lane, -1 for the others, behind a barrier: XLA's CPU fusion
    # would otherwise pull the incentives (several gathers, seven IDM evaluations) into
    # every reader and recompute them once per reader (each output, each pick below).
    choice = jax.lax.optimization_barrier(jnp.where(eligible & (left_ok | right_ok), to, -1))
    allowed = choice >= 0
    fired = allowed & (u.lc_fire.reshape(-1) < -jnp.expm1(-p.mobil_rate * p.dt))
    # Two starters toward one lane, closer than a follower's safe distance: the lower goes.
    # Only the first STARTERS acting drivers are compared pair by pair: comparing all V**2
    # pairs was most of the traffic's step.
    pick = fired[None, :] & ((jnp.cumsum(fired) - 1)[None, :] == jnp.arange(STARTERS)[:, None])
    k = jnp.sum(jnp.where(pick, i[None, :], 0), axis=1)  # (K,) the picked drivers (0: none)
    valid = jnp.any(pick, axis=1)  # (K,)
    x, v, to_k = a.x[k], a.v[k], choice[k]
    near = jnp.abs(x[:, None] - x[None, :]) < (
        p.vehicle_length + p.idm_s0 + jnp.maximum(v[:, None], v[None, :]) * p.idm_time_headway
    )
    clash = (to_k[None, :] == to_k[:, None]) & valid[None, :] & near  # (K, K)
    first = jnp.arange(STARTERS)
    go = valid & ~jnp.any(clash & (first[None, :] < first[:, None]), axis=1)  # (K,)
    start = jnp.any(pick & go[:, None], axis=0)  # (N,)
    shape = tr.x.shape
    return Decision(*(b.reshape(shape) for b in (allowed, fired, start, choice)))


def advance(tr: Traffic, moved: Array, d: Decision, u: TrafficDraws, p: EnvParams) -> Traffic:
    """The lane changes one step later: started where ``d.start`` and the vehicle is still on
    the road (``moved``: the slots' ``active`` after the move, before inflow), and every clock
    on by dt."""
    start = d.start & moved
    return tr.replace(
        lane=jnp.where(start, d.to, tr.lane),
        lane_from=jnp.where(start, tr.lane, tr.lane_from),
        lc_time=jnp.where(start, 0.0, jnp.minimum(tr.lc_time + p.dt, NEVER)),
        lc_dur=jnp.where(
            start, between(u.lc_time, p.lane_change_time_min, p.lane_change_time_max), tr.lc_dur
        ),
    )


def counts(d: Decision, a: Around, eg: Ego, p: EnvParams) -> dict[str, Array]:
    """The step's lane changes for ``info``: how many were allowed, fired and started (``()``
    int32 each), and ``cut_in`` (``()`` bool): one starts into the ego's gap, between its lead
    and lag in the target lane, or into the ego's lane between it and its leader, once the ego
    has its command (GAP or RL)."""
    ego = a.x.shape[0] - 1
    x = a.x[:ego].reshape(d.start.shape)

    def between_of(lane: Array, lo: Array) -> Array:  # (lanes, slots) bool
        lead, has_lead = a.lead[lane, ego], a.has_lead[lane, ego]
        hi = jnp.where(has_lead, a.x[lead], FAR)
        return (d.to == lane) & (x > lo) & (x < hi)

    t = eg.target
    lag = jnp.where(a.has_lag[t, ego], a.x[a.lag[t, ego]], -FAR)
    into = between_of(t, lag) | between_of(current_lane(eg, p), eg.x)
    return {
        "lc_allowed": jnp.sum(d.allowed, dtype=jnp.int32),
        "lc_fired": jnp.sum(d.fired, dtype=jnp.int32),
        "lc_started": jnp.sum(d.start, dtype=jnp.int32),
        "cut_in": (eg.phase >= GAP) & jnp.any(d.start & into),
    }
