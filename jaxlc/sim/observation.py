"""The observation: one table of what each entry is, how it is scaled and how it reflects,
read by the simulator (``observation`` below), the scripted controller, the gym bounds and the
mirror augmentation alike; and the function that computes it from a state.

Entry ``i`` of the ``(OBS_DIM,)`` observation is ``raw_i / scale_i``; a scale named by a string
is that ``EnvParams`` field (it can differ between models). Gaps are net (bumper to bumper),
clipped to ``GAP_CLIP`` m; a missing vehicle reads gap 100 m and dv 0, dv = v_other - v.
``mirror`` is the entry's sign under the reflection y -> -y (lateral quantities flip).

    from jaxlc.sim.observation import INDEX, scale
    offset_m = obs[..., INDEX["offset"]] * scale("offset", params)
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxlc.sim import gap, kinematics
from jaxlc.sim.idm import NO_LEADER_GAP
from jaxlc.sim.leaders import occupancy
from jaxlc.sim.reward import step_limit
from jaxlc.sim.road import (
    current_lane,
    ego_yaw_rate,
    lane_offset,
    lane_row,
    lateral_offset,
    road_curvature,
    target_frame,
)
from jaxlc.sim.state import Ego, EnvParams, EnvState, Traffic, episode_params


class Entry(NamedTuple):
    name: str
    scale: float | str  # divisor; a str names the EnvParams field that holds it
    mirror: float  # sign under y -> -y
    meaning: str


GAP_CLIP = (-10.0, 100.0)  # m, net gaps are clipped to this before scaling

LAYOUT: tuple[Entry, ...] = (
    Entry("v", 30.0, 1.0, "ego speed, m/s"),
    Entry("accel", 3.0, 1.0, "ego longitudinal acceleration, m/s^2"),
    Entry("psi", 0.1, -1.0, "heading relative to the lane's direction, rad"),
    # kappa_d*v holds a lane of a curve; with env.yaw_rate_obs = "lane" relative to that: 0
    Entry("omega", 0.1, -1.0, "yaw rate, rad/s"),
    Entry("offset", "offset_obs_scale", -1.0, "signed offset from the target lane's centre, m"),
    Entry("held", 1.0, -1.0, "action being executed (held for k steps), in [-1, 1]"),
    # 0 unless terminal_timeout: a bootstrapped timeout must not be observable (``observation``).
    Entry("time", "manoeuvre_time_limit", 1.0, "manoeuvre time, s"),
    Entry("curvature", 0.01, -1.0, "the episode's road curvature (centre line), 1/m"),
    Entry("lead_gap", 100.0, 1.0, "net gap to the target lane's leader, m"),
    Entry("lead_dv", 10.0, 1.0, "target lane's leader speed minus ego speed, m/s"),
    Entry("lag_gap", 100.0, 1.0, "net gap to the target lane's follower, m"),
    Entry("lag_dv", 10.0, 1.0, "target lane's follower speed minus ego speed, m/s"),
    Entry("own_gap", 100.0, 1.0, "net gap to the leader in the lane holding the ego's centre, m"),
    Entry("own_dv", 10.0, 1.0, "that leader's speed minus ego speed, m/s"),
)
OBS_DIM = len(LAYOUT)
INDEX = {e.name: i for i, e in enumerate(LAYOUT)}
# The task is symmetric under y -> -y (lanes alike, left and right commands equally likely,
# the reward even in omega, a_lat and offset), so a reflected transition (obs and next obs
# times these signs, action negated) is one the env could have produced: ``ddpg.mirror``.
MIRROR_SIGNS = tuple(e.mirror for e in LAYOUT)


def scale(name: str, params: EnvParams):
    """The divisor of entry ``name`` under ``params`` (a float, or a traced param)."""
    s = LAYOUT[INDEX[name]].scale
    return getattr(params, s) if isinstance(s, str) else s


def _highest(p: EnvParams, name: str) -> float:
    """The field's value, or its range's upper end where it is drawn per episode."""
    drawn = getattr(p, "drawn", ())
    v = float(getattr(p, name))
    return max(v, float(p.ranges[drawn.index(name)][1])) if name in drawn else v


def bounds(params: EnvParams) -> tuple[np.ndarray, np.ndarray]:
    """``(low, high)`` float32 bounds of every observation taken while the ego is under RL
    control (the only ones the decision-step wrappers return).

    Each follows from the simulator: speeds never exceed ``max(entry_speed_max,
    desired_speed_max)`` (IDM never accelerates past v0); IDM acceleration lies in
    [-idm_b_max, idm_a_max]; psi and omega are zeroed when the gap is accepted and then grow by
    at most ``max_yaw_acc*dt`` per step for at most ``n = step_limit(p)``
    steps; the offset starts at +-lane_width and moves at most ``v_max*dt`` a step, and a
    manoeuvre ends once it passes ``border``; gaps are clipped to ``GAP_CLIP``. Each bound is
    widened by 0.1 % (at least 1e-3) for float32 rounding.

    On a curved road the RL phase starts with the lane-holding yaw rate kappa_d*v (|kappa_d| <=
    K, the largest path curvature within ``border`` of a lane's centre), so |omega| <=
    K*v_max + A*dt*n, and the yaw rate relative to the lane's (psi's rate, obs[3] with
    ``env.yaw_rate_obs = "lane"``) is at most A*dt*k + 2*K*v_max at step k: psi gains
    2*K*v_max*n*dt over the straight road's bound.
    """
    p = params
    v_max = max(_highest(p, "entry_speed_max"), _highest(p, "desired_speed_max"))
    dt = float(p.dt)
    n = int(step_limit(p))
    drawn = bool(getattr(p, "curvature_drawn", False))
    ends = (p.curvature_min, p.curvature_max) if drawn else (p.curvature,)
    kappa = max(abs(float(k)) for k in ends)
    offset = max(_highest(p, "lane_width"), float(p.border)) + v_max * dt
    d_max = 0.5 * (int(p.lanes) - 1) * _highest(p, "lane_width") + offset  # from the road's centre
    # Past kappa*d = 1 the lines would cross the bend's centre: no bound (no sane road).
    k_path = kappa / (1.0 - kappa * d_max) if kappa * d_max < 1.0 else np.inf
    omega = float(p.max_yaw_acc) * dt * n + k_path * v_max * (2.0 if lane_relative(p) else 1.0)
    psi = float(p.max_yaw_acc) * dt * dt * n * (n + 1) / 2 + 2.0 * k_path * v_max * n * dt
    raw = {  # name -> (low, high) before scaling
        "v": (0.0, v_max),
        "accel": (-float(p.idm_b_max), float(p.idm_a_max)),
        "psi": (-psi, psi),
        "omega": (-omega, omega),
        "offset": (-offset, offset),
        "held": (-1.0, 1.0),
        "time": (0.0, n * dt),
        "curvature": (-kappa, kappa),
    }
    for side in ("lead", "lag", "own"):
        raw[f"{side}_gap"] = GAP_CLIP
        raw[f"{side}_dv"] = (-v_max, v_max)
    assert raw.keys() == INDEX.keys()
    div = np.array([float(scale(e.name, p)) for e in LAYOUT])
    low = np.array([raw[e.name][0] for e in LAYOUT]) / div
    high = np.array([raw[e.name][1] for e in LAYOUT]) / div
    pad = 1e-3 * np.maximum(1.0, np.abs(np.where(np.isfinite(high), high, 0.0)))
    return (low - pad).astype(np.float32), (high + pad).astype(np.float32)


def lane_relative(p: EnvParams) -> bool:
    """obs[3] is the yaw rate relative to the lane's (``env.yaw_rate_obs = "lane"``)."""
    return p.yaw_rate_obs == "lane"


def meaning(e: Entry, p: EnvParams) -> str:
    """What entry ``e`` holds under ``p`` (obs[3] follows ``env.yaw_rate_obs``)."""
    if e.name == "omega" and lane_relative(p):
        return "yaw rate relative to the lane's (0 holds the lane on a bend), rad/s"
    return e.meaning


def observe_lanes(
    tr: Traffic, eg: Ego, p: EnvParams, kappa: Array | None = None
) -> tuple[gap.Neighbours, Array, Array]:
    """Target-lane neighbours (positions in s) and the net gap (metres along the lane) and
    speed of the leader in the ego's current lane (meaningless in WAIT). With ``env.mobil``
    they are found by position among the bodies that count in the lane (``b1_mask`` is then
    ``(rows * slots,)``)."""
    kappa = p.curvature if kappa is None else kappa
    cur = current_lane(eg, p)
    if tr.lane is None:  # rows are lanes
        row = lambda a: lane_row(a, eg.target, p.lanes)  # noqa: E731
        nb = gap.neighbours(row(tr.x), row(tr.v), row(tr.v0), row(tr.active), eg.x)
        cx, cv = lane_row(tr.x, cur, p.lanes), lane_row(tr.v, cur, p.lanes)  # (slots,)
        in_cur = lane_row(tr.active, cur, p.lanes)
    else:  # every body that counts in the lane, a vehicle changing lanes in both
        occ = occupancy(tr, p).reshape(p.lanes, -1)  # (lanes, rows * slots)
        flat = lambda a: a.reshape(-1)  # noqa: E731
        in_target = lane_row(occ, eg.target, p.lanes)
        nb = gap.neighbours(flat(tr.x), flat(tr.v), flat(tr.v0), in_target, eg.x)
        cx, cv, in_cur = flat(tr.x), flat(tr.v), lane_row(occ, cur, p.lanes)
    ahead = in_cur & (cx > eg.x)
    lx = jnp.min(jnp.where(ahead, cx, gap.FAR))
    lv = jnp.max(jnp.where(ahead & (cx == lx), cv, -gap.FAR))
    has = jnp.any(ahead)
    c = kinematics.lane_scale(kappa, lane_offset(cur, p))
    return nb, gap.net_gap(lx * c, eg.x * c, p.vehicle_length, has), jnp.where(has, lv, eg.v)


def target_gaps(state: EnvState, p: EnvParams) -> tuple[Array, Array]:
    """``(lead_gap, lag_gap)``: net gaps (m along the target lane) from the ego to the target
    lane's lead and lag vehicles; meaningless where ``state.nb.has_a1``/``has_b1`` is False."""
    return target_gaps_of(state.nb, state.ego, road_curvature(state, p), p)


def target_gaps_of(nb: gap.Neighbours, ego: Ego, kappa: Array, p: EnvParams) -> tuple[Array, Array]:
    """``target_gaps`` of the neighbours ``nb`` and the ego ``ego`` on a road of curvature
    ``kappa`` (before the state that holds them is built)."""
    nb, x = target_frame(nb, ego, kappa, p)
    return nb.a1_x - p.vehicle_length - x, x - p.vehicle_length - nb.b1_x


def observation(state: EnvState, p: EnvParams) -> Array:
    """``(OBS_DIM,)`` normalised observation of ``state``: the entries of ``LAYOUT``, each raw
    value divided by its scale; read with the episode's drawn values (``EnvState.episode``)."""
    p = episode_params(state, p)
    eg, nb = state.ego, state.nb

    def gap_m(g: Array, present: Array) -> Array:
        return jnp.where(present, jnp.clip(g, *GAP_CLIP), GAP_CLIP[1])

    def dv(v_other: Array, present: Array) -> Array:
        return jnp.where(present, v_other - eg.v, 0.0)

    has_leader = state.leader_gap < NO_LEADER_GAP
    kappa = road_curvature(state, p)
    lead_gap, lag_gap = target_gaps(state, p)
    raw = {
        "v": eg.v,
        "accel": eg.accel,
        "psi": eg.psi,
        "omega": ego_yaw_rate(eg, kappa, p) if lane_relative(p) else eg.omega,
        "offset": lateral_offset(eg, p),
        "held": eg.held,
        # A truncated timeout is bootstrapped, so the time must not be observed: values at
        # time = limit are never learned as current states (Pardo et al., 2018).
        "time": jnp.where(p.terminal_timeout, eg.steps * p.dt, 0.0),
        "curvature": kappa * jnp.ones_like(eg.v),
        "lead_gap": gap_m(lead_gap, nb.has_a1),
        "lead_dv": dv(nb.a1_v, nb.has_a1),
        "lag_gap": gap_m(lag_gap, nb.has_b1),
        "lag_dv": dv(nb.b1_v, nb.has_b1),
        "own_gap": gap_m(state.leader_gap, has_leader),
        "own_dv": dv(state.leader_v, has_leader),
    }
    obs = jnp.stack([raw[e.name] / scale(e.name, p) for e in LAYOUT])
    return obs.astype(jnp.float32)
