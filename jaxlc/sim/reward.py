"""Reward, eqs. (8)-(11) of the paper, and the episode's termination rules.

    r_s = -w1*|omega| - w2*|a_lat|                        (8)  smoothness
    r_e = -w3*dt                                          (9)  elapsed time
    r_d = -w4*|dd|                   if |dd| <= D          (10)
          -w4*|dd| * 10/(1-gamma)    if |dd| >  D          (11)
    r   = r_s + r_e + r_d

omega (rad/s) and the lateral offset dd (m) are those after the step, a_lat (rad/s^2) the
executed yaw acceleration. A collision ends the episode with the out-of-bounds penalty at
|dd| = max(|dd|, D). Every term is returned on its own so it can be logged.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

# Why an episode ended (info["reason"]).
NONE, SUCCESS, OUT_OF_BOUNDS, COLLISION, TIMEOUT, NO_GAP = 0, 1, 2, 3, 4, 5
REASONS = ("none", "success", "out_of_bounds", "collision", "timeout", "no_gap")


def reward_terms(
    omega: Array, a_lat: Array, offset: Array, collided: Array, p
) -> tuple[Array, Array, Array]:
    """``(r_s, r_e, r_d)`` for one RL step (``p``: EnvParams; all scaled by reward_scale)."""
    r_s = -p.w1 * jnp.abs(omega) - p.w2 * jnp.abs(a_lat)
    r_e = -p.w3 * p.dt * jnp.ones_like(omega)
    dev = jnp.abs(offset)
    beyond = -p.w4 * jnp.maximum(dev, p.border) * 10.0 / (1.0 - p.gamma)
    r_d = jnp.where(collided | (dev > p.border), beyond, -p.w4 * dev)
    return p.reward_scale * r_s, p.reward_scale * r_e, p.reward_scale * r_d


def end_reason(
    offset: Array, psi: Array, omega: Array, manoeuvre_steps: Array, collided: Array, p
) -> Array:
    """Reason code after an RL step; the first that holds of collision, out of bounds,
    success, timeout (NONE while the manoeuvre goes on)."""
    out = jnp.abs(offset) > p.border
    success = (
        (jnp.abs(offset) <= p.success_offset)
        & (jnp.abs(psi) <= p.success_heading)
        & (jnp.abs(omega) <= p.success_yaw_rate)
    )
    # Counting steps, not summing dt, keeps the 10 s limit exact in float32.
    timeout = manoeuvre_steps >= jnp.round(p.manoeuvre_time_limit / p.dt)
    return jnp.select(
        [collided, out, success, timeout],
        [COLLISION, OUT_OF_BOUNDS, SUCCESS, TIMEOUT],
        NONE,
    ).astype(jnp.int32)
