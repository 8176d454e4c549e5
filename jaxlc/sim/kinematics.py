"""The ego's lateral kinematics and body geometry in the road frame.

The action is the yaw acceleration a_lat (rad/s^2), integrated by semi-implicit Euler:
    omega <- omega + a_lat*dt
    psi   <- psi + (omega - kappa*v)*dt       (heading relative to a road of curvature kappa)
    x     <- x + v*cos(psi)*dt ;  y <- y + v*sin(psi)*dt
x is the front-bumper position along the road, y the lateral position of the centre line of
the body (lane l spans [l*W, (l+1)*W]).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array


def lateral_step(
    x: Array, y: Array, psi: Array, omega: Array, v: Array, a_lat: Array, kappa: Array, dt: Array
) -> tuple[Array, Array, Array, Array]:
    """One semi-implicit Euler step; returns the new ``(x, y, psi, omega)``."""
    omega = omega + a_lat * dt
    psi = psi + (omega - kappa * v) * dt
    return x + v * jnp.cos(psi) * dt, y + v * jnp.sin(psi) * dt, psi, omega


def half_extents(psi: Array, length: Array, width: Array) -> tuple[Array, Array]:
    """Half sizes along x and y of the axis-aligned box around a body rotated by ``psi``."""
    c, s = jnp.abs(jnp.cos(psi)), jnp.abs(jnp.sin(psi))
    return 0.5 * (length * c + width * s), 0.5 * (length * s + width * c)


def lanes_overlapped(y: Array, half_y: Array, lanes: int, lane_width: Array) -> Array:
    """``(lanes,)`` bool: which lanes the body's lateral extent [y - half_y, y + half_y] touches."""
    lo = jnp.arange(lanes) * lane_width
    return (y + half_y > lo) & (y - half_y < lo + lane_width)
