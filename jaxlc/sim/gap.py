"""Gap selection: the lead and lag of a lane around the ego, and which gap to merge into.

Candidates are the gap beside the ego (lag B1, lead A1), the gap ahead (A1, A2) and the gap
behind (B2, B1). The gap beside is acceptable when both net gaps are at least
``s0 + gap_time_headway*v`` and the lag's IDM deceleration with the ego as its leader is no
harsher than ``-b_safe`` (MOBIL's safety criterion), and (with ``gap_min_ttc`` > 0) when
neither the lead nor the lag, at today's speeds, would come within ``s0`` of the ego in
``gap_min_ttc`` s: a time-to-collision test. A gap ahead or behind is acceptable when
it is long enough to hold the ego with those margins. If the gap beside is not acceptable,
the ego adapts its speed toward the nearest acceptable candidate by taking that gap's lead
vehicle as an extra IDM leader (A2 ahead, B1 behind, A1 when none is acceptable).

Positions are metres along the lane (``scaled`` converts the road frame's s to them).
Every function works on one lane row ``(slots,)`` with masked reductions (no sort, no
gather), so it vectorises over envs under ``vmap``.
"""

from __future__ import annotations

import flax.struct
import jax.numpy as jnp
from jax import Array

from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params

FAR = 1e6  # position standing in for a missing vehicle


@flax.struct.dataclass
class Neighbours:
    """Vehicles of one lane around a reference position x_ref (scalars per env).

    A1/A2: nearest and second-nearest with front bumper ahead of x_ref; B1/B2: nearest and
    second-nearest at or behind it. Missing vehicles have x = +-FAR, speed 0 and
    ``has_* = False``.
    """

    a1_x: Array
    a1_v: Array
    a2_x: Array
    a2_v: Array
    b1_x: Array
    b1_v: Array
    b1_v0: Array
    b2_x: Array
    b2_v: Array
    b1_mask: Array  # (slots,) bool: which slot is B1 (the lag), for the yield rule
    has_a1: Array
    has_a2: Array
    has_b1: Array
    has_b2: Array


def _pick(mask: Array, value: Array) -> Array:
    """The value at the (single) masked slot; 0 when the mask is empty."""
    return jnp.where(jnp.any(mask), jnp.max(jnp.where(mask, value, -FAR)), 0.0)


def neighbours(x: Array, v: Array, v0: Array, active: Array, x_ref: Array) -> Neighbours:
    """Lead and lag vehicles of one lane: ``x, v, v0, active`` are ``(slots,)``."""
    ahead = active & (x > x_ref)
    behind = active & ~(x > x_ref)
    a1_x = jnp.min(jnp.where(ahead, x, FAR))
    is_a1 = ahead & (x == a1_x)
    ahead2 = ahead & (x > a1_x)
    a2_x = jnp.min(jnp.where(ahead2, x, FAR))
    b1_x = jnp.max(jnp.where(behind, x, -FAR))
    is_b1 = behind & (x == b1_x)
    behind2 = behind & (x < b1_x)
    b2_x = jnp.max(jnp.where(behind2, x, -FAR))
    return Neighbours(
        a1_x=a1_x,
        a1_v=_pick(is_a1, v),
        a2_x=a2_x,
        a2_v=_pick(ahead2 & (x == a2_x), v),
        b1_x=b1_x,
        b1_v=_pick(is_b1, v),
        b1_v0=_pick(is_b1, v0),
        b2_x=b2_x,
        b2_v=_pick(behind2 & (x == b2_x), v),
        b1_mask=is_b1,
        has_a1=jnp.any(ahead),
        has_a2=jnp.any(ahead2),
        has_b1=jnp.any(behind),
        has_b2=jnp.any(behind2),
    )


def scaled(nb: Neighbours, c: Array) -> Neighbours:
    """``nb`` with its positions multiplied by ``c``: from s along the road's reference line
    to metres along the lane (``jaxlc.sim.kinematics.lane_scale``); every gap test below
    takes positions in metres along the lane. ``c`` is 1 on a straight road."""
    return nb.replace(a1_x=nb.a1_x * c, a2_x=nb.a2_x * c, b1_x=nb.b1_x * c, b2_x=nb.b2_x * c)


def net_gap(x_front: Array, x_back: Array, length: Array, present: Array) -> Array:
    """Bumper-to-bumper gap from the vehicle at ``x_back`` to the one ahead at ``x_front``."""
    return jnp.where(present, x_front - length - x_back, NO_LEADER_GAP)


def beside_acceptable(nb: Neighbours, x_ego: Array, v_ego: Array, p) -> Array:
    """The acceptance test of the gap beside the ego (``p``: EnvParams)."""
    lead_gap = net_gap(nb.a1_x, x_ego, p.vehicle_length, nb.has_a1)
    lag_gap = net_gap(x_ego, nb.b1_x, p.vehicle_length, nb.has_b1)
    lead_ok = lead_gap >= p.idm_s0 + p.gap_time_headway * v_ego
    lag_ok = lag_gap >= p.idm_s0 + p.gap_time_headway * nb.b1_v
    lag_acc = idm_with_params(nb.b1_v, nb.b1_v0, lag_gap, v_ego, p)
    lag_safe = ~nb.has_b1 | (lag_acc >= -p.b_safe)
    # Anticipation: the gaps after gap_min_ttc s at today's speeds still hold s0. A lag that
    # does not yield keeps its speed until the ego's body is in its lane, so MOBIL's test of
    # its braking (as if it yielded) alone lets a fast lag catch a slow ego alongside.
    lead_ahead = lead_gap - jnp.maximum(v_ego - nb.a1_v, 0.0) * p.gap_min_ttc >= p.idm_s0
    lag_behind = lag_gap - jnp.maximum(nb.b1_v - v_ego, 0.0) * p.gap_min_ttc >= p.idm_s0
    return lead_ok & lag_ok & lag_safe & lead_ahead & lag_behind


def target_leader(nb: Neighbours, x_ego: Array, v_ego: Array, p) -> tuple[Array, Array]:
    """Net gap and speed of the lead vehicle of the gap the ego steers toward (GAP phase)."""
    margin = 2.0 * p.idm_s0 + p.vehicle_length
    # Gap ahead (A1, A2): room for the ego between them.
    ahead_len = jnp.where(nb.has_a2, nb.a2_x - p.vehicle_length - nb.a1_x, FAR)
    ahead_ok = nb.has_a1 & (ahead_len >= margin + p.gap_time_headway * (v_ego + nb.a1_v))
    # Gap behind (B2, B1).
    behind_len = jnp.where(nb.has_b2, nb.b1_x - p.vehicle_length - nb.b2_x, FAR)
    behind_ok = nb.has_b1 & (behind_len >= margin + p.gap_time_headway * (v_ego + nb.b2_v))
    go_ahead = ahead_ok & (~behind_ok | (nb.a1_x - x_ego <= x_ego - nb.b1_x))
    go_behind = behind_ok & ~go_ahead
    lead_x = jnp.where(go_ahead, nb.a2_x, jnp.where(go_behind, nb.b1_x, nb.a1_x))
    lead_v = jnp.where(go_ahead, nb.a2_v, jnp.where(go_behind, nb.b1_v, nb.a1_v))
    present = jnp.where(go_ahead, nb.has_a2, jnp.where(go_behind, True, nb.has_a1))
    return net_gap(lead_x, x_ego, p.vehicle_length, present), lead_v
