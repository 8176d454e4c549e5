"""Pictures of the simulator: one env's state as an RGB array (the gymnasium wrappers'
``render()``), and the road frame mapped to the world and back (``road_to_world``,
``world_to_road``; the evaluation's scenes draw with the same mapping).

The road frame is Frenet (``jaxlc.sim.kinematics``): s along the reference line, d across it
(> 0 to the left). The world is the plane of the tangent at one point of that line: X along
the tangent, Y to the left, the point at (0, 0). With R = 1/kappa the bend's centre is at
(0, R): a point at (s, d) lies at r = R - d from it, at the angle theta = s/R.
"""

from __future__ import annotations

import jax
import numpy as np

from jaxlc.sim.leaders import vehicle_y
from jaxlc.sim.reward import step_limit
from jaxlc.sim.road import origin_lane, reference_y, road_curvature
from jaxlc.sim.state import EnvParams, EnvState

VERGE = (96, 140, 80)  # RGB outside the road


def road_to_world(s: np.ndarray, d: np.ndarray, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """``(X, Y)`` of road-frame points ``(s, d)`` (any shape, float) on a road of curvature
    ``kappa``, the frame's origin at (0, 0); the identity when ``kappa == 0``."""
    if kappa == 0.0:
        return s, d
    radius = 1.0 / kappa
    r, theta = radius - d, s * kappa  # distance from the bend's centre, angle turned
    return r * np.sin(theta), radius - r * np.cos(theta)


def world_to_road(x: np.ndarray, y: np.ndarray, kappa: float) -> tuple[np.ndarray, np.ndarray]:
    """``(s, d)`` of world points ``(X, Y)``, the inverse of ``road_to_world`` (any shape)."""
    if kappa == 0.0:
        return x, y
    radius = 1.0 / kappa
    s = radius * np.arctan2(x / radius, (radius - y) / radius)
    return s, radius - np.sign(radius) * np.hypot(x, y - radius)


def render_frame(
    state: EnvState,
    params: EnvParams,
    *,
    view_m: float = 120.0,
    px_per_m: float = 8.0,
) -> np.ndarray:
    """``(H, W, 3)`` uint8 picture of one env's state (host or device arrays), a window of
    ``view_m`` metres of road centred on the ego: lanes, traffic (blue), the ego (red, drawn
    at its heading), the target lane shaded, and a bar along the top that fills up with the
    manoeuvre time. A curved road is drawn bent (``_bend``): the scene is drawn in the road
    frame, then mapped onto the arc; the picture is taller by the window's sagitta at the
    params' sharpest curvature, so every frame of an env has one shape."""
    tr, eg = jax.device_get((state.traffic, state.ego))
    kappa = float(road_curvature(state, params))
    p = params
    lanes, w, length, width = (
        p.lanes,
        float(p.lane_width),
        float(p.vehicle_length),
        float(p.vehicle_width),
    )
    s = px_per_m
    bar, shoulder = 6, int(round(1.5 * s))
    road_px = int(round(lanes * w * s))
    h_px, w_px = bar + 2 * shoulder + road_px, int(round(view_m * s))
    img = np.empty((h_px, w_px, 3), np.uint8)
    img[:] = VERGE
    x0 = float(eg.x) - 0.5 * length - 0.5 * view_m  # world x of the left edge

    def col(x: float) -> int:
        return int(round((x - x0) * s))

    def row(y: float) -> int:  # lane 0 at the bottom, y upwards
        return int(round(bar + shoulder + (lanes * w - y) * s))

    def fill(x_lo: float, x_hi: float, y_lo: float, y_hi: float, rgb: tuple[int, ...]) -> None:
        c0, c1 = max(col(x_lo), 0), min(col(x_hi), w_px)
        r0, r1 = max(row(y_hi), 0), min(row(y_lo), h_px)
        if c0 < c1 and r0 < r1:
            img[r0:r1, c0:c1] = rgb

    fill(x0, x0 + view_m, 0.0, lanes * w, (70, 70, 74))
    target = int(eg.target)
    if target != origin_lane(p):
        fill(x0, x0 + view_m, target * w, (target + 1) * w, (92, 92, 98))
    # Markings: solid road edges, 3 m dashes every 12 m between lanes, fixed to the road.
    line = max(1, int(round(0.15 * s)))
    for y in (0.0, lanes * w):
        r = row(y)
        img[max(r - line, 0) : r + line, :] = (235, 235, 235)
    for lane in range(1, lanes):
        r = row(lane * w)
        for start in np.arange(np.floor(x0 / 12.0) * 12.0, x0 + view_m, 12.0):
            c0, c1 = max(col(start), 0), min(col(start + 3.0), w_px)
            if c0 < c1:
                img[max(r - line // 2 - 1, 0) : r + line // 2 + 1, c0:c1] = (235, 235, 235)
    # Traffic: axis-aligned boxes, front bumper at x.
    active, xs = np.asarray(tr.active), np.asarray(tr.x)
    if tr.lane is None:  # rows are lanes
        ys = (np.arange(lanes)[:, None] + 0.5) * w + np.zeros_like(xs)
    else:  # with env.mobil: every body where it is, between two lanes while it changes
        ys = np.asarray(vehicle_y(tr, p))
    for x, yc in zip(xs[active], ys[active], strict=True):
        fill(x - length, x, yc - 0.5 * width, yc + 0.5 * width, (60, 120, 220))
    _draw_ego(img, eg, length, width, x0, bar + shoulder + lanes * w * s, s)
    ends = (p.curvature_min, p.curvature_max) if p.curvature_drawn else (p.curvature,)
    k_max = max(abs(float(k)) for k in ends)
    if k_max > 0.0:
        extra = int(np.ceil(view_m**2 * k_max / 8.0 * s))  # sagitta of the window, px
        ref_row = bar + shoulder + (lanes * w - float(reference_y(p))) * s
        img = _bend(img, kappa, bar, extra, ref_row, s)
    # Manoeuvre-time bar.
    limit = max(1, int(step_limit(p)))
    img[:bar] = (30, 30, 30)
    img[:bar, : int(w_px * min(int(eg.steps), limit) / limit)] = (240, 190, 40)
    return img


def _draw_ego(
    img: np.ndarray, eg, length: float, width: float, x0: float, y0_row: float, s: float
) -> None:
    """The ego's rotated box (red), rasterised over its bounding rectangle; world x ``x0`` is
    column 0 and y = 0 is pixel row ``y0_row`` (y upwards), ``s`` px per metre."""
    h_px, w_px = img.shape[:2]
    c, sn = np.cos(float(eg.psi)), np.sin(float(eg.psi))
    cx, cy = float(eg.x) - 0.5 * length * c, float(eg.y) - 0.5 * length * sn
    half = 0.5 * (length * abs(c) + width * abs(sn)), 0.5 * (length * abs(sn) + width * abs(c))
    c0 = max(int(round((cx - half[0] - x0) * s)), 0)
    c1 = min(int(round((cx + half[0] - x0) * s)) + 1, w_px)
    r0 = max(int(round(y0_row - (cy + half[1]) * s)), 0)
    r1 = min(int(round(y0_row - (cy - half[1]) * s)) + 1, h_px)
    if c0 < c1 and r0 < r1:
        xx = x0 + (np.arange(c0, c1) + 0.5) / s - cx
        yy = (y0_row - (np.arange(r0, r1) + 0.5)) / s - cy
        along = xx[None, :] * c + yy[:, None] * sn
        across = -xx[None, :] * sn + yy[:, None] * c
        inside = (np.abs(along) <= 0.5 * length) & (np.abs(across) <= 0.5 * width)
        img[r0:r1, c0:c1][inside] = (220, 40, 40)


def _bend(
    img: np.ndarray, kappa: float, top: int, extra: int, ref_row: float, px_per_m: float
) -> np.ndarray:
    """The road-frame picture ``img`` (columns: s, rows below ``top``: d, the reference line
    at row ``ref_row``) mapped onto a road of curvature ``kappa``, ``extra`` rows taller above
    and below; its centre column stays where it is. Each pixel of the bent picture is the
    world point (X along the tangent at the window's centre, Y to the left) whose road-frame
    coordinates (``world_to_road``) pick the nearest pixel of ``img`` (the verge outside it)."""
    h, w_px, _ = img.shape
    rows = np.arange(top, h + 2 * extra) + 0.5
    cols = np.arange(w_px) + 0.5
    X = (cols[None, :] - 0.5 * w_px) / px_per_m
    Y = (ref_row + extra - rows[:, None]) / px_per_m
    s_w, d = np.broadcast_arrays(*world_to_road(X, Y, kappa))
    c = np.round(0.5 * w_px + s_w * px_per_m - 0.5).astype(int)
    r = np.round(ref_row - d * px_per_m - 0.5).astype(int)
    ok = (c >= 0) & (c < w_px) & (r >= top) & (r < h)
    out = np.empty((top + rows.size, w_px, 3), np.uint8)
    out[:top] = img[:top]
    out[top:] = VERGE
    out[top:][ok] = img[r[ok], c[ok]]
    return out
