"""A scripted reference lane-change controller on the same action (yaw acceleration).

In the lane's frame (``kinematics``) the lateral offset e obeys, for small heading, the
triple integrator
    e' = v*psi,  psi' = omega_r,  omega_r' = a_lat - kappa_d*a_x
where omega_r = omega - kappa_d*v*cos(psi) is the yaw rate relative to the lane's,
kappa_d = kappa/(1 - kappa*d) the curvature of the ego's line at offset d from the road's
centre line, and a_x the ego's longitudinal acceleration (holding a curve at a changing speed
takes a yaw acceleration kappa_d*a_x). So the law

    a_lat = kappa_d*a_x*cos(psi) - (p^3*e + 3*p^2*v*psi + 3*p*v*omega_r) / v

(curvature feed-forward, then state feedback) places all three closed-loop poles at -p: a
smooth, overshoot-free lane change lasting about 5/p s. On a straight road it is the plain
pole placement.

kappa is the observation's road curvature; d comes from the offset e to the target lane and
the road's layout (``params``): the ego starts on lane ``lanes // 2`` and its target lies
across its offset (e = y - y_target < 0: the target is the next lane up), so d = d_target + e.
With kappa in place of kappa_d the yaw rate of the target lane would be off by
v*kappa^2*d/(1 - kappa*d), which the feedback turns into a standing offset of
3*v^2*kappa^2*d/p^2 (0.9 m at kappa = 0.01, v = 33 m/s, d = 3.7 m): no success.
It reads only the observation and the params, so it is a drop-in baseline for a learned
actor.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxlc.sim.env import EnvParams, action_dim
from jaxlc.sim.observation import INDEX, scale

DEFAULT_POLE = 1.2  # 1/s: a lane change of about 4-5 s, inside the 3-8 s of human drivers
_READ = ("v", "accel", "psi", "omega", "offset", "curvature")


def scripted_action(obs: Array, params: EnvParams, pole: float = DEFAULT_POLE) -> Array:
    """``(..., OBS_DIM) -> (..., action_dim)`` action in [-1, 1] from the pole-placement law;
    with ``longitudinal = "policy"`` its second entry is 0: the IDM's acceleration, unchanged
    (the baseline drives as the paper's ego does)."""
    raw = {n: obs[..., INDEX[n]] * scale(n, params) for n in _READ}
    v = jnp.maximum(raw["v"], 1.0)
    psi, e, kappa = raw["psi"], raw["offset"], raw["curvature"]
    target = params.lanes // 2 - jnp.sign(e)  # the target lies across the offset
    d = (target + 0.5) * params.lane_width - 0.5 * params.lanes * params.lane_width + e
    kappa_d = kappa / (1.0 - kappa * d)  # exactly 0 on a straight road
    cos_psi = jnp.cos(psi)
    omega_r = raw["omega"] - kappa_d * raw["v"] * cos_psi  # relative to the lane's yaw rate
    feed_forward = kappa_d * raw["accel"] * cos_psi
    a_lat = feed_forward - (pole**3 * e + 3 * pole**2 * v * psi + 3 * pole * v * omega_r) / v
    lateral = jnp.clip(a_lat / params.max_yaw_acc, -1.0, 1.0)[..., None]
    if action_dim(params) == 1:
        return lateral
    return jnp.concatenate([lateral, jnp.zeros_like(lateral)], axis=-1)
