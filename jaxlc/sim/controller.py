"""A scripted reference lane-change controller on the same action (yaw acceleration).

The lateral offset e obeys, for small heading, the triple integrator
    e' = v*psi,  e'' = v*omega,  e''' = v*a_lat,
so the state feedback  a_lat = -(p^3*e + 3*p^2*v*psi + 3*p*v*omega) / v  places all three
closed-loop poles at -p: a smooth, overshoot-free lane change lasting about 5/p s. It reads
only the observation, so it is a drop-in baseline for a learned actor.
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array

from jaxlc.sim.env import EnvParams
from jaxlc.sim.observation import INDEX, scale

DEFAULT_POLE = 1.2  # 1/s: a lane change of about 4-5 s, inside the 3-8 s of human drivers


def scripted_action(obs: Array, params: EnvParams, pole: float = DEFAULT_POLE) -> Array:
    """``(..., OBS_DIM) -> (..., 1)`` action in [-1, 1] from the pole-placement law."""
    raw = {n: obs[..., INDEX[n]] * scale(n, params) for n in ("v", "psi", "omega", "offset")}
    v = jnp.maximum(raw["v"], 1.0)
    psi, omega, e = raw["psi"], raw["omega"], raw["offset"]
    a_lat = -(pole**3 * e + 3 * pole**2 * v * psi + 3 * pole * v * omega) / v
    return jnp.clip(a_lat / params.max_yaw_acc, -1.0, 1.0)[..., None]
