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
second: by thinning, an eligible driver weighs a change when the step's draw ``lc_fire`` fires
and starts it when MOBIL allows, so only the few drivers whose draw fired are weighed, the
first ``mobil_deciders`` of an env in slot order (``params``: a binomial tail of 1e-6 per
env-step at the config's rate and a full road; a driver past them weighs again on a later
step's draw). Of two drivers starting toward the same lane within a safe distance of each
other on one step, the one in the lower slot goes. The change lasts a drawn
``U(lane_change_time_min, _max)`` s along ``leaders.profile``; meanwhile the body counts in
both lanes (``leaders.occupancy``): it leads and follows in each.
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
from jax import Array

from jaxlc.sim import leaders
from jaxlc.sim.gap import FAR
from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params
from jaxlc.sim.leaders import Around, changing
from jaxlc.sim.road import current_lane
from jaxlc.sim.state import GAP, Ego, EnvParams, Traffic, TrafficDraws, between

NEVER = 1e4  # s since the last lane change of a vehicle that has made none


class Decision(NamedTuple):
    """One step's lane-change decisions, ``(lanes, slots)`` each (slot order)."""

    eligible: Array  # bool: on the road, not changing lanes, its last start long enough ago
    weighed: Array  # bool: eligible, its draw fired, and among the env's first deciders
    allowed: Array  # bool: weighed, and MOBIL allows a change to one side
    start: Array  # bool: allowed and not held back by a nearer starter
    to: Array  # int32 the lane it moves to where allowed, else -1


def _idm(a: Around, f: Array, lead: Array, present: Array, lane: Array, p: EnvParams):
    """``(acc, gap)`` of vehicles ``f`` following ``lead`` (where ``present``) in ``lane``."""
    c = a.scale[lane]
    g = jnp.where(present, a.x[lead] * c - a.length[lead] - a.x[f] * c, NO_LEADER_GAP)
    v_lead = jnp.where(present, a.v[lead], a.v[f])
    return idm_with_params(a.v[f], a.v0[f], g, v_lead, p, a.free[f]), g


def _in_lane(t: Array, lane: Array) -> Array:
    """``t[lane[j], j]`` (``t``: ``(lanes, K)``), by a one-hot over the few lanes: a gather's
    two index arrays cost XLA's CPU more than the pick."""
    pick = lane[None, :] == jnp.arange(t.shape[0])[:, None]  # (lanes, K)
    if t.dtype == jnp.bool_:
        return jnp.any(pick & t, axis=0)
    return jnp.sum(jnp.where(pick, t, 0), axis=0, dtype=t.dtype)


def _lead_lag(a: Around, lags: tuple[Array, Array], lane: Array, cols: Array):
    """``(lead, has_lead, lag, has_lag)`` of vehicles ``cols`` ``(K,)`` in lanes ``lane``
    (``lags``: ``leaders.lags`` of ``cols``)."""
    ahead = (a.lead[:, cols], a.has_lead[:, cols])
    return tuple(_in_lane(t, lane) for t in (*ahead, *lags))


def _written(a: Array) -> Array:
    """``a`` itself, written by a scatter: XLA's CPU fusion does not pull a scatter's inputs
    into its readers, which would otherwise recompute them (here the step's draws, gathers and
    IDM evaluations) once per element they read."""
    return jnp.zeros_like(a).at[jnp.arange(a.shape[0])].set(a, unique_indices=True)


def decide(tr: Traffic, a: Around, u: TrafficDraws, p: EnvParams) -> Decision:
    """Which vehicles start a lane change on this step, and to which lane (``a``: the state's
    ``leaders.around``; positions are those of the state before the step's move)."""
    n, k = tr.x.size, p.mobil_deciders
    i = jnp.arange(n)
    eligible = tr.active.reshape(-1) & ~changing(tr).reshape(-1)
    eligible &= tr.lc_time.reshape(-1) >= p.mobil_interval
    acts = eligible & (u.lc_fire.reshape(-1) < -jnp.expm1(-p.mobil_rate * p.dt))  # (N,)
    # A driver's place among them (>= K: none): how many act up to it, by a product with a
    # triangle of ones (exact: ones summed to at most N, in float32 as in TF32 or bfloat16),
    # which XLA's CPU runs faster than a cumsum.
    upto = (i[:, None] <= i[None, :]).astype(jnp.float32)  # (N, N) [j, i]: j <= i
    at = jnp.where(acts, (acts.astype(jnp.float32) @ upto).astype(jnp.int32) - 1, k)
    # (K,) the deciders, n where none: compacted by a scatter, which also keeps the draws
    # from being recomputed by every reader (``_written``).
    c = jnp.full(k, n, jnp.int32).at[at].set(i, mode="drop")
    valid = c < n
    c = jnp.minimum(c, n - 1)
    lane = tr.lane.reshape(-1)[c]
    behind = leaders.lags(a, c)  # (lanes, K) each
    cur_lead, has_cur, old, has_old = _lead_lag(a, behind, lane, c)
    a_c, _ = _idm(a, c, cur_lead, has_cur, lane, p)
    a_o, _ = _idm(a, old, c, True, lane, p)
    at_o, _ = _idm(a, old, cur_lead, has_cur, lane, p)
    gain_o = jnp.where(has_old, at_o - a_o, 0.0)

    def side(d: int) -> tuple[Array, Array, Array]:
        to = lane + d
        ok = (to >= 0) & (to < p.lanes)
        to = jnp.clip(to, 0, p.lanes - 1)
        lead, has_lead, new, has_new = _lead_lag(a, behind, to, c)
        at_c, front = _idm(a, c, lead, has_lead, to, p)
        a_n, _ = _idm(a, new, lead, has_lead, to, p)
        at_n, back = _idm(a, new, c, True, to, p)
        gain_n = jnp.where(has_new, at_n - a_n, 0.0)
        incentive = at_c - a_c + p.mobil_politeness * (gain_n + gain_o)
        incentive = incentive - p.mobil_threshold - d * p.mobil_bias_right
        safe = (at_c >= -p.b_safe) & (front >= p.idm_s0)
        safe &= ~has_new | ((at_n >= -p.b_safe) & (back >= p.idm_s0))
        return ok & safe & (incentive > 0.0), incentive, to

    left_ok, left_gain, left_to = side(1)
    right_ok, right_gain, right_to = side(-1)
    go_left = left_ok & (~right_ok | (left_gain >= right_gain))
    to = jnp.where(valid & (left_ok | right_ok), jnp.where(go_left, left_to, right_to), -1)
    to = _written(to.astype(jnp.int32))  # (K,) the new lane, -1 where not allowed
    allowed = to >= 0
    # Two starters toward one lane, closer than a follower's safe distance: the lower goes.
    x, v = a.x[c], a.v[c]
    near = jnp.abs(x[:, None] - x[None, :]) < (
        p.vehicle_length + p.idm_s0 + jnp.maximum(v[:, None], v[None, :]) * p.idm_time_headway
    )
    clash = (to[None, :] == to[:, None]) & allowed[None, :] & near  # (K, K)
    first = jnp.arange(k)
    start = allowed & ~jnp.any(clash & (first[None, :] < first[:, None]), axis=1)
    # Back to slots by a scatter.
    to_slot = jnp.where(valid, c, n)  # (K,) n: written past the end and dropped

    def slots(b: Array, fill: int) -> Array:  # (K,) -> (N,)
        return jnp.full(n + 1, fill, b.dtype).at[to_slot].set(b)[:n]

    out = (eligible, slots(valid, 0), slots(allowed, 0), slots(start, 0), slots(to, -1))
    return Decision(*(b.reshape(tr.x.shape) for b in out))


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
    """The step's lane changes for ``info``: how many drivers were eligible, weighed a change,
    were allowed one and started it (``()`` int32 each), and ``cut_in`` (``()`` bool): one
    starts into the ego's gap, between its lead and lag in the target lane, or into the ego's
    lane between it and its leader, once the ego has its command (GAP or RL)."""
    ego = a.x.shape[0] - 1
    x = a.x[:ego].reshape(d.start.shape)

    def between_of(lane: Array, lo: Array) -> Array:  # (lanes, slots) bool
        lead, has_lead = a.lead[lane, ego], a.has_lead[lane, ego]
        hi = jnp.where(has_lead, a.x[lead], FAR)
        return (d.to == lane) & (x > lo) & (x < hi)

    t = eg.target
    lag, has_lag = (b[t, 0] for b in leaders.lags(a, jnp.array([ego])))
    lag = jnp.where(has_lag, a.x[lag], -FAR)
    into = between_of(t, lag) | between_of(current_lane(eg, p), eg.x)
    return {
        "lc_eligible": jnp.sum(d.eligible, dtype=jnp.int32),
        "lc_weighed": jnp.sum(d.weighed, dtype=jnp.int32),
        "lc_allowed": jnp.sum(d.allowed, dtype=jnp.int32),
        "lc_started": jnp.sum(d.start, dtype=jnp.int32),
        "cut_in": (eg.phase >= GAP) & jnp.any(d.start & into),
    }
