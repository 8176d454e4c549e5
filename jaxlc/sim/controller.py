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
the road's layout (``params``): the ego starts on ``road.origin_lane`` and its target lies
across its offset (e = y - y_target < 0: the target is the next lane up), so d = d_target + e.
With kappa in place of kappa_d the yaw rate of the target lane would be off by
v*kappa^2*d/(1 - kappa*d), which the feedback turns into a standing offset of
3*v^2*kappa^2*d/p^2 (0.9 m at kappa = 0.01, v = 33 m/s, d = 3.7 m): no success.
It reads only the observation and the params, so it is a drop-in baseline for a learned
actor. ``fitting_action`` drives the same law toward the origin lane's centre, and adjusts
the speed, until the accepted gap fits the headway norm (a reference for joint control), and
``assist_action`` adds it under a policy (``env.assist = "fitting"`` or ``"fitting_hold"``).
"""

from __future__ import annotations

from typing import Any

import jax.numpy as jnp
from jax import Array

from jaxlc.sim.ego import held_action, held_long_action
from jaxlc.sim.observation import INDEX, lane_relative, observation, scale
from jaxlc.sim.road import origin_lane
from jaxlc.sim.state import RL, EnvParams, EnvState, action_dim

DEFAULT_POLE = 1.2  # 1/s: a lane change of about 4-5 s, inside the 3-8 s of human drivers
_READ = ("v", "accel", "psi", "omega", "offset", "curvature")


def scripted_action(obs: Array, params: EnvParams, pole: float = DEFAULT_POLE) -> Array:
    """``(..., OBS_DIM) -> (..., action_dim)`` action in [-1, 1] from the pole-placement law;
    with ``longitudinal = "policy"`` its second entry is 0: the IDM's acceleration, unchanged
    (the baseline drives as the paper's ego does)."""
    raw = {n: obs[..., INDEX[n]] * scale(n, params) for n in _READ}
    lateral = _pole_placement(raw, raw["offset"], params, pole)
    if action_dim(params) == 1:
        return lateral
    return jnp.concatenate([lateral, jnp.zeros_like(lateral)], axis=-1)


def _pole_placement(raw: dict[str, Array], e: Array, params: EnvParams, pole: float) -> Array:
    """``(..., 1)`` yaw action of the law above toward the lane at offset ``e`` (m) from the
    ego; the ego's own position is read from the observed offset to the target lane."""
    v = jnp.maximum(raw["v"], 1.0)
    psi, kappa = raw["psi"], raw["curvature"]
    target = origin_lane(params) - jnp.sign(raw["offset"])  # the target lies across the offset
    d = (target + 0.5) * params.lane_width - 0.5 * params.lanes * params.lane_width
    d = d + raw["offset"]  # the ego's distance from the road's centre line
    kappa_d = kappa / (1.0 - kappa * d)  # exactly 0 on a straight road
    cos_psi = jnp.cos(psi)
    omega_r = raw["omega"]  # relative to the lane's yaw rate, as observed or from it:
    if not lane_relative(params):
        omega_r = omega_r - kappa_d * raw["v"] * cos_psi
    feed_forward = kappa_d * raw["accel"] * cos_psi
    a_lat = feed_forward - (pole**3 * e + 3 * pole**2 * v * psi + 3 * pole * v * omega_r) / v
    return jnp.clip(a_lat / params.max_yaw_acc, -1.0, 1.0)[..., None]


# The gap-fitting controller's constants (``fitting_action``), picked by hand
# (docs/decisions.md, "a driver-assist layer under the policy").
FIT_HEADWAY = 1.0  # s: the 0.9 s headway norm plus a margin for the prediction
FIT_LOOKAHEAD = 0.8  # s: the gaps are predicted at today's speeds this far ahead
FIT_GO_AFTER = 3.0  # s after the command: from then on a gap at the acceptance's headway will do
_FIT_READ = _READ + ("time", "lead_gap", "lead_dv", "lag_gap", "lag_dv")


def fitting_action(obs: Array, params: EnvParams, **options: Any) -> Array:
    """``(..., OBS_DIM) -> (..., action_dim)`` actions in [-1, 1] of the gap-fitting
    reference for joint control: ``fitting_and_go``'s action (``options``: its keywords)."""
    return fitting_and_go(obs, params, **options)[0]


def fitting_and_go(
    obs: Array,
    params: EnvParams,
    pole: float = DEFAULT_POLE,
    headway: float = FIT_HEADWAY,
    lookahead: float = FIT_LOOKAHEAD,
    go_after: float = FIT_GO_AFTER,
    time: Array | None = None,
) -> tuple[Array, Array]:
    """``(action, go)``: ``(..., action_dim)`` actions that fit the ego into the accepted gap
    before it crosses, and ``(...)`` bool, whether it goes (False while it holds the origin
    lane for the gap to fit).

    It holds the origin lane (``_pole_placement`` toward the origin lane's centre) until the
    time headways to the target lane's lead and lag, predicted ``lookahead`` s ahead at
    today's speeds, are both at least ``headway``; then, or at once when the gap is too short
    ever to fit (lead gap + lag gap < ``headway`` * (ego's speed + lag's)), or from
    ``go_after`` s after the command with a gap at ``gap_time_headway``, or once its body
    overlaps the target lane, it changes lane as ``scripted_action`` does. While waiting, the
    longitudinal action (``longitudinal = "policy"``) brakes fully for a short lead or a faster
    lag and accelerates fully away from a slower lag. ``time``: the manoeuvre's time in s
    (default: the observed one, 0 unless ``env.terminal_timeout``). Odd under the road's
    reflection in the lateral action, even in the longitudinal one."""
    raw = {n: obs[..., INDEX[n]] * scale(n, params) for n in _FIT_READ}
    v = jnp.maximum(raw["v"], 1.0)
    v_lag = jnp.maximum(raw["v"] + raw["lag_dv"], 1.0)
    lead_h = (raw["lead_gap"] + raw["lead_dv"] * lookahead) / v  # a missing vehicle: 100 m
    lag_h = (raw["lag_gap"] - raw["lag_dv"] * lookahead) / v_lag
    fits = (lead_h >= headway) & (lag_h >= headway)
    too_short = raw["lead_gap"] + raw["lag_gap"] < headway * (v + v_lag)
    now = raw["time"] if time is None else time
    late = (now >= go_after) & (jnp.minimum(lead_h, lag_h) >= params.gap_time_headway)
    e = raw["offset"]  # from the target lane's centre; about a lane width while waiting
    entered = jnp.abs(e) < 0.5 * (params.lane_width + params.vehicle_width)  # heading ~ 0
    go = fits | too_short | late | entered
    toward = jnp.where(go, e, e - jnp.sign(e) * params.lane_width)  # target or origin centre
    lateral = _pole_placement(raw, toward, params, pole)
    if action_dim(params) == 1:
        return lateral, go
    short_lead, short_lag = lead_h < headway, lag_h < headway
    brake = short_lead | (short_lag & (raw["lag_dv"] > 0.0))
    longitudinal = jnp.where(fits, 0.0, jnp.where(brake, -1.0, jnp.where(short_lag, 1.0, 0.0)))
    return jnp.concatenate([lateral, longitudinal[..., None]], axis=-1), go


def assist_action(state: EnvState, params: EnvParams) -> tuple[Array, Array]:
    """``(action_dim,)``: what the driver-assist layer of ``env.assist`` adds to the policy's
    executed action in the RL phase (0 before it): ``fitting_action`` on the state's
    observation, with the manoeuvre time it has run (the assist keeps its own clock, whether
    or not the policy observes the time); and ``()`` bool, whether it holds the origin lane
    (in the RL phase, the gap not fitting yet)."""
    obs = observation(state, params)
    a, go = fitting_and_go(obs, params, time=state.ego.steps * params.dt)
    in_rl = state.ego.phase == RL
    return jnp.where(in_rl, a, 0.0), in_rl & ~go


def baseline_action(obs: Array, params: EnvParams) -> Array:
    """The held-out evaluation's baseline row: ``scripted_action``, or with a driver-assist
    layer (``env.assist``) nothing on top of it (the assist alone, itself a scripted
    controller)."""
    if params.assist != "none":
        return jnp.zeros(obs.shape[:-1] + (action_dim(params),), obs.dtype)
    return scripted_action(obs, params)


def executed_action(state: EnvState, action: Array, p: EnvParams) -> tuple:
    """``(held, held_long, lat, lon)``: the policy's held actions (``held_long`` None unless
    longitudinal = "policy") and the executed ones, with the assist's (env.assist) added."""
    held = held_action(state.ego, action, p)
    held_long = held_long_action(state.ego, action, p)
    lat, lon = held, held_long
    if p.assist != "none":  # static: the default's program has no assist in it
        extra, holding = assist_action(state, p)  # (action_dim,), ()
        w = p.assist_authority  # the residual's share of each bound
        lat = jnp.clip(w * held + extra[0], -1.0, 1.0)
        if p.assist == "fitting_hold":
            # The hold sits on the out-of-bounds border (the origin lane's centre, a lane
            # width from the target's): any outward residual would end the manoeuvre there.
            lat = jnp.where(holding, extra[0], lat)
        lon = None if held_long is None else jnp.clip(w * held_long + extra[1], -1.0, 1.0)
    return held, held_long, lat, lon
