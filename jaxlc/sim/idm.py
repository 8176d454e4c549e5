"""Intelligent Driver Model (Treiber, Hennecke & Helbing 2000), the car-following law of
every vehicle and of the ego's longitudinal control.

    s* = s0 + max(0, v*T + v*dv / (2*sqrt(a_max*b)))      dv = v - v_lead (closing speed)
    a  = a_max * (1 - (v/v0)**delta - (s*/s)**2)            clipped below at -b_max

All arguments broadcast, so one call serves every vehicle of every env.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

# Net gap standing in for "no leader": large enough that (s*/s)^2 vanishes in float32.
NO_LEADER_GAP = 1e4
# Smallest net gap used in the formula: a touching or overlapping leader means full braking,
# not a division by zero.
MIN_GAP = 1e-2


def idm_acceleration(
    v: Array,
    v0: Array,
    gap: Array,
    v_lead: Array,
    a_max: Array | float,
    b: Array | float,
    time_headway: Array | float,
    s0: Array | float,
    delta: Array | float,
    b_max: Array | float,
    free: Array | None = None,
) -> Array:
    """IDM acceleration (m/s^2) for speed ``v``, desired speed ``v0`` and net ``gap`` (m)
    to a leader driving at ``v_lead``; every argument broadcasts (e.g. ``(lanes, slots)``).
    ``free``: ``free_road(v, v0, delta)`` where the caller has it already."""
    dv = v - v_lead
    s_star = s0 + jnp.maximum(0.0, v * time_headway + v * dv / (2.0 * jnp.sqrt(a_max * b)))
    free = free_road(v, v0, delta) if free is None else free
    interaction = jnp.square(s_star / jnp.maximum(gap, MIN_GAP))
    return jnp.maximum(a_max * (1.0 - free - interaction), -b_max)


def free_road(v: Array, v0: Array, delta: Array | float) -> Array:
    """The IDM's free-road term ``(v/v0)**delta``, a function of the follower alone: a traffic
    that weighs one vehicle behind several leaders (MOBIL, a body in two lanes) computes it
    once per vehicle, as ``pow`` is the costliest operation of the law on XLA's CPU."""
    return jnp.power(jnp.maximum(v, 0.0) / v0, delta)


def idm_with_params(
    v: Array, v0: Array, gap: Array, v_lead: Array, p, free: Array | None = None
) -> Array:
    """``idm_acceleration`` with the IDM constants of ``p`` (an ``EnvParams``)."""
    return idm_acceleration(
        v,
        v0,
        gap,
        v_lead,
        p.idm_a_max,
        p.idm_b,
        p.idm_time_headway,
        p.idm_s0,
        p.idm_delta,
        p.idm_b_max,
        free,
    )
