"""The ego's lateral kinematics and body geometry in the road frame (Frenet).

The road is a band of concentric arcs around a reference line: the road's centre line, of
curvature kappa (1/m; kappa > 0 bends toward +y, the higher lane indices, i.e. to the left).
A position is (s, d): s the arc length along the reference line, d = y - y_ref the signed
offset across it. The line at offset d is an arc of curvature

    kappa_d = kappa / (1 - kappa*d)                                (``path_curvature``)

and a length ds of the reference line is ``(1 - kappa*d) * ds`` metres along it
(``lane_scale``), so every vehicle's s is compared radially: two vehicles at the same s are
side by side, and the net gap between two vehicles of one lane is ``(s1 - s0) * c - L``.

The ego's heading psi is relative to the direction of the line it is on, omega its yaw rate
(inertial), v its speed along its heading. The exact Frenet equations are

    s'   = v*cos(psi) / (1 - kappa*d)
    d'   = v*sin(psi)
    psi' = omega - kappa*s' = omega - kappa_d*v*cos(psi)

(the reference line turns by kappa per metre of s, so a heading relative to it loses
kappa*s'). The action is the yaw acceleration a_lat (rad/s^2); one step is semi-implicit
Euler in that order:

    omega <- omega + a_lat*dt
    psi   <- psi + (omega - kappa_d*v*cos(psi))*dt
    s     <- s + v*cos(psi)/(1 - kappa*d)*dt ;  d <- d + v*sin(psi)*dt

with kappa_d and the scale at the d before the step. Holding a line of offset d (psi = 0)
takes omega = kappa_d*v; ``relative_yaw_rate`` = omega - kappa_d*v*cos(psi) = psi' is the yaw
rate relative to the lane's, which the success test and the reward's comfort term use. At
kappa = 0 every factor is exactly 1 or 0, so the step is the straight road's x, y to the bit.

x (the code's name for s) is the front bumper, y the lateral position of the centre line of
the body (lane l spans [l*W, (l+1)*W]).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax import Array


def lane_scale(kappa: Array, d: Array) -> Array:
    """Metres along the line at offset ``d`` per metre of the reference line, ``1 - kappa*d``
    (exactly 1 on a straight road)."""
    return 1.0 - kappa * d


def path_curvature(kappa: Array, d: Array) -> Array:
    """Curvature of the line at offset ``d``: ``kappa / (1 - kappa*d)`` (exactly 0 at
    ``kappa = 0``)."""
    return kappa / lane_scale(kappa, d)


def relative_yaw_rate(omega: Array, psi: Array, v: Array, kappa: Array, d: Array) -> Array:
    """Yaw rate relative to the direction of the line at offset ``d``: psi' of the step's
    equations, ``omega - kappa_d*v*cos(psi)``; ``omega`` itself on a straight road."""
    return omega - path_curvature(kappa, d) * v * jnp.cos(psi)


def lateral_step(
    x: Array,
    y: Array,
    psi: Array,
    omega: Array,
    v: Array,
    a_lat: Array,
    kappa: Array,
    dt: Array,
    y_ref: Array | float = 0.0,
) -> tuple[Array, Array, Array, Array]:
    """One semi-implicit Euler step of the Frenet equations (module docstring) on a road of
    curvature ``kappa`` whose reference line is at ``y = y_ref``; returns the new
    ``(x, y, psi, omega)``."""
    d = y - y_ref
    omega = omega + a_lat * dt
    psi = psi + (omega - path_curvature(kappa, d) * v * jnp.cos(psi)) * dt
    x = x + v * jnp.cos(psi) / lane_scale(kappa, d) * dt
    return x, y + v * jnp.sin(psi) * dt, psi, omega


def half_extents(psi: Array, length: Array, width: Array) -> tuple[Array, Array]:
    """Half sizes along x and y of the axis-aligned box around a body rotated by ``psi``."""
    c, s = jnp.abs(jnp.cos(psi)), jnp.abs(jnp.sin(psi))
    return 0.5 * (length * c + width * s), 0.5 * (length * s + width * c)


def lanes_overlapped(y: Array, half_y: Array, lanes: int, lane_width: Array) -> Array:
    """``(..., lanes)`` bool: which lanes the body's lateral extent [y - half_y, y + half_y]
    touches (``y``, ``half_y``: any batch shape)."""
    lo = jnp.arange(lanes) * lane_width
    y, half_y = jnp.asarray(y)[..., None], jnp.asarray(half_y)[..., None]
    return (y + half_y > lo) & (y - half_y < lo + lane_width)
