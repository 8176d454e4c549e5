"""Safety and comfort of one lane change, by the norms an automated-driving engineer applies
(their table and sources: docs/usage.md, "Held-out lane changes, safety and comfort"; the
choices: docs/decisions.md, "headway and TTC in the norms", "the 5 s norm's time").

Measured on every step of the RL phase, the start state included: lateral acceleration
a_y = v * omega; lateral jerk as ISO 11270 reads it, ``(a_y(t) - a_y(t - 0.5 s)) / 0.5 s``;
time-to-collision ``net gap / closing speed`` (inf when not closing or missing, 0 once the
boxes overlap along the road) and time headway ``net gap / follower's speed`` to the target
lane's lead and lag and the own lane's leader, where they share a lane with the ego
(``counted``, recorded as ``COUNTED``); UN R79's manoeuvre, from the step the body first
overlaps the target lane to the step it first leaves the origin lane (``crossed``). A
collision is attributed to the vehicle hit (``PARTNERS``): the lane it drives in and whether
its centre is ahead of the ego's.
"""

from __future__ import annotations

import flax.struct
import jax.numpy as jnp
from jax import Array

from jaxlc.sim.idm import NO_LEADER_GAP
from jaxlc.sim.leaders import changing
from jaxlc.sim.observation import target_gaps
from jaxlc.sim.road import body_in_lane, current_lane, origin_lane

# Each norm: (measure, bound, True when the measure must stay below the bound, source).
NORMS = (
    ("lcm_s", 5.0, True, "UN R79 (ACSF C): lane change manoeuvre (line to line) in under 5 s"),
    ("peak_lat_acc", 3.0, True, "ISO 11270: lateral acceleration <= 3 m/s²"),
    ("peak_lat_jerk", 5.0, True, "ISO 11270: lateral jerk (0.5 s average) <= 5 m/s³"),
    ("min_ttc_s", 1.5, False, "time-to-collision >= 1.5 s (critical below)"),
    ("min_thw_s", 0.9, False, "time headway >= 0.9 s (critical below)"),
)
JERK_WINDOW_S = 0.5
# The rule by which headway and TTC count, as eval/heldout.json records it.
COUNTED = (
    "where they share a lane: the target lane's lead and lag from the step the ego's body first "
    "overlaps the target lane, the own lane's leader while the body overlaps the own lane"
)
VEHICLES = ("lead", "lag", "own")  # target lane's lead and lag, the own-lane leader
PARTNERS = ("none", "target_lead", "target_lag", "own_leader", "own_follower")
# What the vehicle hit was doing (env.mobil, env.braking): a bit each.
HAZARDS = ("none", "braking", "changing_lanes", "braking_and_changing_lanes")


def ttc(gap: Array, v_follower: Array, v_leader: Array, present: Array) -> Array:
    """Time-to-collision, s: ``gap / (v_follower - v_leader)`` while closing, else inf;
    0 at a gap <= 0 (the boxes overlap along the road), inf for a missing vehicle."""
    closing = v_follower - v_leader
    t = jnp.where(closing > 0.0, gap / jnp.where(closing > 0.0, closing, 1.0), jnp.inf)
    return jnp.where(present, jnp.where(gap <= 0.0, 0.0, t), jnp.inf)


def headway(gap: Array, v_follower: Array, present: Array) -> Array:
    """Time headway, s: ``gap / v_follower``, the ``ttc`` to a standing leader (inf for a
    standing follower or no vehicle, 0 at a gap <= 0)."""
    return ttc(gap, v_follower, 0.0, present)


def conflicts(state, p) -> tuple[Array, Array]:
    """``(ttc, thw)``, each ``(..., 3)`` over ``VEHICLES``, of an ``EnvState`` (any batch
    shape; ``p``: EnvParams)."""
    eg, nb = state.ego, state.nb
    lead_gap, lag_gap = target_gaps(state, p)  # metres along the target lane
    has_own = state.leader_gap < NO_LEADER_GAP
    pairs = (  # (gap, follower's speed, leader's speed, present) per vehicle of VEHICLES
        (lead_gap, eg.v, nb.a1_v, nb.has_a1),
        (lag_gap, nb.b1_v, eg.v, nb.has_b1),
        (state.leader_gap, eg.v, state.leader_v, has_own),
    )
    t = jnp.stack([ttc(*q) for q in pairs], axis=-1)
    return t, jnp.stack([headway(g, vf, ok) for g, vf, _, ok in pairs], axis=-1)


def counted(state, p, entered: Array) -> tuple[Array, Array]:
    """``(mask, entered)``: which of ``VEHICLES`` count at this step, ``(..., 3)`` bool, and
    whether the ego's body has overlapped the target lane by this step, ``(...)`` (``entered``:
    the same before it). The ego starts in the origin lane (``road.origin_lane``)."""
    eg = state.ego
    origin = origin_lane(p)
    entered = entered | body_in_lane(eg, eg.target, p)
    # state.leader_* is the leader of the lane holding the centre: the origin lane's till then
    own = body_in_lane(eg, origin, p) & (current_lane(eg, p) == origin)
    return jnp.stack([entered, entered, own], axis=-1), entered


def crossed(state, p) -> Array:
    """``(...)`` bool: the ego's body is wholly out of the origin lane (UN R79's
    lane change manoeuvre ends at the first such step after the body entered the target lane)."""
    return ~body_in_lane(state.ego, origin_lane(p), p)


def lateral_acc(state) -> Array:
    """``(...)`` lateral acceleration of the ego, v * omega (m/s^2)."""
    return state.ego.v * state.ego.omega


def jerk_window(p) -> int:
    """Steps in the 0.5 s moving average of the lateral jerk (at least 1)."""
    return max(1, int(round(JERK_WINDOW_S / float(p.dt))))


def windowed_jerk(history: Array, a_y: Array, dt: float) -> tuple[Array, Array]:
    """``(jerk, history)``: the lateral jerk averaged over the window that ``history (...,
    n)`` (the last n lateral accelerations, oldest first) spans, and the history with ``a_y``
    appended."""
    n = history.shape[-1]
    jerk = (a_y - history[..., 0]) / (n * dt)
    return jerk, jnp.concatenate([history[..., 1:], a_y[..., None]], axis=-1)


@flax.struct.dataclass
class Watch:
    """What the measures carry from one RL step to the next; leaves ``(policies, cases, ...)``."""

    lat: Array  # (..., window) the last 0.5 s of lateral acceleration, oldest first, m/s^2
    long: Array  # (..., window) of longitudinal acceleration
    entered: Array  # bool: the ego's body has overlapped the target lane by this step


def watch(state, p) -> tuple[Watch, Array]:
    """``(watch, counted)`` at the manoeuvre's start: each acceleration held at its start value
    (the ego drove straight before; its jerk before the start is not known), and whose
    headway and TTC count there (``counted``)."""
    a0 = lateral_acc(state)
    window = a0.shape + (jerk_window(p),)
    lat, long = (jnp.broadcast_to(a[..., None], window) for a in (a0, state.ego.accel))
    mask, entered = counted(state, p, jnp.zeros(a0.shape, bool))
    return Watch(lat, long, entered), mask


def observe(w: Watch, state, p) -> tuple[Watch, tuple[Array, Array, Array]]:
    """``(watch, (lateral jerk, longitudinal jerk, counted))`` after a step to ``state``."""
    lat_jerk, lat = windowed_jerk(w.lat, lateral_acc(state), p.dt)
    long_jerk, long = windowed_jerk(w.long, state.ego.accel, p.dt)
    mask, entered = counted(state, p, w.entered)
    return Watch(lat, long, entered), (lat_jerk, long_jerk, mask)


def partner(overlap: Array, traffic, ego, p) -> Array:
    """``(...)`` int32 index into ``PARTNERS`` of the vehicle an ego box overlaps (the
    ``(..., lanes, slots)`` mask ``overlap``; ``traffic`` the ``Traffic`` after the step); 0
    when none. A vehicle changing lanes is in the target lane when it counts there."""
    traffic_x = traffic.x
    lanes = jnp.arange(p.lanes)[:, None]
    if traffic.lane is None:
        in_target = lanes == ego.target[..., None, None]
    else:
        target = ego.target[..., None, None]
        leaving = changing(traffic) & (traffic.lane_from == target)
        in_target = (traffic.lane == target) | leaving
    # Centres along the road: the ego's box is heading-aligned, front bumper at x.
    ahead = traffic_x - 0.5 * p.vehicle_length > (ego.x - 0.5 * p.vehicle_length)[..., None, None]
    code = jnp.where(in_target, jnp.where(ahead, 1, 2), jnp.where(ahead, 3, 4))
    return jnp.max(jnp.where(overlap, code, 0), axis=(-2, -1)).astype(jnp.int32)


def hazard(overlap: Array, traffic) -> Array:
    """``(...)`` int32 index into ``HAZARDS`` of what the vehicles an ego box overlaps
    (``(..., lanes, slots)``) were doing: braking in an event, changing lanes, both."""
    code = jnp.zeros(overlap.shape[:-2], jnp.int32)
    if traffic.brake_left is not None:
        code += jnp.any(overlap & (traffic.brake_left > 0.0), axis=(-2, -1))
    if traffic.lane is not None:
        code += 2 * jnp.any(overlap & changing(traffic), axis=(-2, -1))
    return code
