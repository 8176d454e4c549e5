"""The lane-change environment: a functional, gymnax-style API over a batched traffic sim.

    env, params = jaxlc.make()
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

One env is one highway: ``lanes`` lanes of ``road_length`` metres, each with
``slots_per_lane`` vehicle slots used as a ring buffer in entry order. Only the ego changes
lanes, so vehicles of a lane never pass each other and a vehicle's leader is simply the slot
written before it: no search (see ``_ring_leaders``). The ego is kept apart from the slots.

An episode of the ego goes through four phases (``info["phase"]``):
  WAIT   no ego; the next vehicle to enter the middle lane becomes the ego;
  CRUISE the ego follows IDM until it has travelled ``command_distance``;
  GAP    a left or right command is issued; gap selection looks for an acceptable gap
         (``gap.py``), adapting the ego's speed, for at most ``gap_time_limit`` s;
  RL     the action steers the ego (yaw acceleration) until success, out of bounds,
         collision or timeout; only these steps are transitions (``info["rl_step"]``).
When an episode ends the ego leaves the road and the env goes back to WAIT on the same step
(auto-reset); traffic keeps flowing, so no warm-up is needed between episodes. The returned
``obs`` is the observation after the step: on the step an episode ends it is the terminal
observation, which is what a learner bootstraps from.

Observation (``OBS_DIM`` = 14, normalised), in this order:
  0 v/30  1 a_long/3  2 psi/0.1  3 omega/0.1  4 offset/offset_obs_scale (default W = 3.7 m)
  5 held action  6 manoeuvre time/limit (0 unless ``terminal_timeout``: see ``observation``)
  7 curvature*100  8 lead net gap/100  9 lead dv/10  10 lag net gap/100  11 lag dv/10
  12 leader net gap/100 in the lane that holds the ego's centre  13 its dv/10
Gaps are clipped to [-10, 100] m; a missing vehicle reads gap 100 m, dv 0 (dv = v_other - v).

``MIRROR_SIGNS`` reflects an observation across the road's axis (y -> -y): the lateral
entries (2 psi, 3 omega, 4 offset, 5 held action) and the curvature change sign, the rest stays.
"""

from __future__ import annotations

from dataclasses import dataclass

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc import gap, kinematics, reward
from jaxlc.config import Config, EnvConfig
from jaxlc.idm import NO_LEADER_GAP, idm_with_params

WAIT, CRUISE, GAP, RL = 0, 1, 2, 3
PHASES = ("wait", "cruise", "gap", "rl")
OBS_DIM = 14
# The task is symmetric under y -> -y (lanes alike, left and right commands equally likely,
# the reward even in omega, a_lat and offset), so a reflected transition (obs and next obs
# times these signs, action negated) is one the env could have produced: ``ddpg.mirror``.
MIRROR_SIGNS = (1.0, 1.0, -1.0, -1.0, -1.0, -1.0, 1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 1.0)
ACT_DIM = 1
KMH = 1.0 / 3.6
_OBS_SCALE = (30.0, 3.0, 0.1, 0.1)  # v, a_long, psi, omega
_GAP_CLIP = (-10.0, 100.0)


@flax.struct.dataclass
class EnvParams:
    """Simulator parameters in SI units (speeds m/s, inflow veh/s).

    Static fields (``pytree_node=False``) fix array shapes and loop lengths; every other
    field is traced, so models with different values (e.g. the action-update step ``k``)
    can share one compiled program under ``vmap``.
    """

    lanes: int = flax.struct.field(pytree_node=False, default=3)
    slots_per_lane: int = flax.struct.field(pytree_node=False, default=16)
    warmup_steps: int = flax.struct.field(pytree_node=False, default=400)
    road_length: float = 600.0
    lane_width: float = 3.7
    curvature: float = 0.0
    dt: float = 0.1
    vehicle_length: float = 5.0
    vehicle_width: float = 1.8
    entry_speed_min: float = 0.0
    entry_speed_max: float = 40.0 * KMH
    desired_speed_min: float = 80.0 * KMH
    desired_speed_max: float = 120.0 * KMH
    inflow_min: float = 800.0 / 3600.0
    inflow_max: float = 1600.0 / 3600.0
    idm_a_max: float = 1.5
    idm_b: float = 2.0
    idm_time_headway: float = 1.5
    idm_s0: float = 2.0
    idm_delta: float = 4.0
    idm_b_max: float = 9.0
    p_yield: float = 0.5
    command_distance: float = 80.0
    gap_time_limit: float = 5.0
    gap_x_limit: float = 450.0
    gap_time_headway: float = 0.5
    b_safe: float = 4.0
    max_yaw_acc: float = 0.5
    manoeuvre_time_limit: float = 10.0
    terminal_timeout: bool = False
    border: float = 3.7
    success_offset: float = 0.2
    success_heading: float = 0.02
    success_yaw_rate: float = 0.02
    w1: float = 10.0
    w2: float = 5.0
    w3: float = 0.075
    w4: float = 1.0
    reward_scale: float = 1.0
    offset_obs_scale: float = 3.7
    gamma: float = 0.98
    k: int = 1

    @classmethod
    def from_config(cls, env: EnvConfig, gamma: float = 0.98, k: int = 1) -> EnvParams:
        """Convert a validated ``EnvConfig`` (km/h, veh/h) to SI params."""
        values = {f: getattr(env, f) for f in cls.__dataclass_fields__ if hasattr(env, f)}
        for f in ("entry_speed_min", "entry_speed_max", "desired_speed_min", "desired_speed_max"):
            values[f] = values[f] * KMH
        values["inflow_min"] = env.inflow_min / 3600.0
        values["inflow_max"] = env.inflow_max / 3600.0
        values["warmup_steps"] = int(round(env.warmup_time / env.dt))
        return cls(**values, gamma=gamma, k=k)


@flax.struct.dataclass
class Traffic:
    """Vehicles other than the ego; lane arrays are ``(lanes, slots)``, ring buffers."""

    x: Array  # (lanes, slots) front-bumper position, m
    v: Array  # (lanes, slots) speed, m/s
    v0: Array  # (lanes, slots) desired speed, m/s
    active: Array  # (lanes, slots) bool
    tail: Array  # (lanes,) int32, slot the next entrant is written to
    timer: Array  # (lanes,) s until the next entry is due
    next_v: Array  # (lanes,) entry speed of the next entrant
    next_v0: Array  # (lanes,) desired speed of the next entrant
    inflow: Array  # (lanes,) veh/s, drawn per episode


@flax.struct.dataclass
class Ego:
    phase: Array  # () int32, WAIT/CRUISE/GAP/RL
    x: Array  # () front bumper, m
    y: Array  # () lateral position of the body's centre line, m
    v: Array  # () m/s
    v0: Array  # () desired speed, m/s
    accel: Array  # () last longitudinal acceleration, m/s^2
    psi: Array  # () heading relative to the road, rad
    omega: Array  # () yaw rate, rad/s
    held: Array  # () action executed (held for k steps), in [-1, 1]
    target: Array  # () int32 target lane
    steps: Array  # () int32 RL steps done in this manoeuvre
    gap_time: Array  # () s spent looking for a gap
    yielding: Array  # () bool, whether the target lane's lag yields
    ep_return: Array  # () return of the current manoeuvre


@flax.struct.dataclass
class EnvState:
    traffic: Traffic
    ego: Ego
    nb: gap.Neighbours  # target lane around the ego, for this state
    leader_gap: Array  # () net gap to the ego's leader in its own lane
    leader_v: Array  # () that leader's speed
    time: Array  # () int32 steps since reset


@dataclass(frozen=True)
class Box:
    """A box-shaped space (gymnax's ``spaces.Box`` without the dependency)."""

    low: float
    high: float
    shape: tuple[int, ...]
    dtype: jnp.dtype = jnp.float32

    def sample(self, key: Array) -> Array:
        return jax.random.uniform(key, self.shape, self.dtype, self.low, self.high)

    def contains(self, x: Array) -> Array:
        return jnp.all((x >= self.low) & (x <= self.high))


def _ring_leaders(tr: Traffic, p: EnvParams) -> tuple[Array, Array]:
    """Net gap and speed of each slot's leader: the slot written just before it, when that
    slot is occupied and ahead (a full ring's oldest slot has the newest behind it)."""
    px, pv, pa = (jnp.roll(a, 1, axis=-1) for a in (tr.x, tr.v, tr.active))
    has = pa & (px > tr.x)
    return jnp.where(has, px - p.vehicle_length - tr.x, NO_LEADER_GAP), jnp.where(has, pv, tr.v)


def _lane_row(a: Array, lane: Array, lanes: int) -> Array:
    """``a[lane]`` for a traced lane index, as a masked sum (cheaper than a gather under vmap)."""
    sel = (jnp.arange(lanes) == lane)[:, None]
    if a.dtype == jnp.bool_:
        return jnp.any(sel & a, axis=0)
    return jnp.sum(jnp.where(sel, a, 0), axis=0)


def current_lane(eg: Ego, p: EnvParams) -> Array:
    """Index of the lane that holds the ego's centre (the origin lane until it crosses)."""
    return jnp.clip(jnp.floor(eg.y / p.lane_width), 0, p.lanes - 1).astype(jnp.int32)


def _observe_lanes(tr: Traffic, eg: Ego, p: EnvParams) -> tuple[gap.Neighbours, Array, Array]:
    """Target-lane neighbours and the leader in the ego's current lane (meaningless in WAIT)."""
    row = lambda a: _lane_row(a, eg.target, p.lanes)  # noqa: E731
    nb = gap.neighbours(row(tr.x), row(tr.v), row(tr.v0), row(tr.active), eg.x)
    cur = current_lane(eg, p)
    cx, cv = _lane_row(tr.x, cur, p.lanes), _lane_row(tr.v, cur, p.lanes)  # (slots,)
    ahead = _lane_row(tr.active, cur, p.lanes) & (cx > eg.x)
    lx = jnp.min(jnp.where(ahead, cx, gap.FAR))
    lv = jnp.max(jnp.where(ahead & (cx == lx), cv, -gap.FAR))
    has = jnp.any(ahead)
    return nb, gap.net_gap(lx, eg.x, p.vehicle_length, has), jnp.where(has, lv, eg.v)


def lateral_offset(eg: Ego, p: EnvParams) -> Array:
    """Signed offset of the ego from the target lane's centre line, m.

    Measured from the origin lane's centre so that it is exactly +-W when the manoeuvre
    starts (``5.55 - 1.85`` rounds above 3.7 in float32 and would end it at once)."""
    origin = p.lanes // 2
    return (eg.y - (origin + 0.5) * p.lane_width) - (eg.target - origin) * p.lane_width


def observation(state: EnvState, p: EnvParams) -> Array:
    """``(OBS_DIM,)`` normalised observation of ``state`` (order in the module docstring)."""
    eg, nb = state.ego, state.nb
    L = p.vehicle_length

    def gap_obs(g: Array, present: Array) -> Array:
        return jnp.where(present, jnp.clip(g, *_GAP_CLIP), _GAP_CLIP[1]) / 100.0

    def dv_obs(v_other: Array, present: Array) -> Array:
        return jnp.where(present, v_other - eg.v, 0.0) / 10.0

    has_leader = state.leader_gap < NO_LEADER_GAP
    obs = jnp.stack(
        [
            eg.v / _OBS_SCALE[0],
            eg.accel / _OBS_SCALE[1],
            eg.psi / _OBS_SCALE[2],
            eg.omega / _OBS_SCALE[3],
            lateral_offset(eg, p) / p.offset_obs_scale,
            eg.held,
            # A truncated timeout is bootstrapped, so the time must not be observed: values
            # at time = limit are never learned as current states (Pardo et al., 2018).
            jnp.where(p.terminal_timeout, eg.steps * p.dt / p.manoeuvre_time_limit, 0.0),
            p.curvature * 100.0 * jnp.ones_like(eg.v),
            gap_obs(nb.a1_x - L - eg.x, nb.has_a1),
            dv_obs(nb.a1_v, nb.has_a1),
            gap_obs(eg.x - L - nb.b1_x, nb.has_b1),
            dv_obs(nb.b1_v, nb.has_b1),
            gap_obs(state.leader_gap, has_leader),
            dv_obs(state.leader_v, has_leader),
        ]
    )
    return obs.astype(jnp.float32)


def _clean_action(action: Array) -> Array:
    """Any action, NaN and inf included, becomes a finite value in [-1, 1]."""
    a = jnp.reshape(action, (-1,))[0].astype(jnp.float32)
    return jnp.clip(jnp.nan_to_num(a, nan=0.0, posinf=1.0, neginf=-1.0), -1.0, 1.0)


def _advance(
    key: Array, state: EnvState, action: Array, p: EnvParams, spawn: bool
) -> tuple[EnvState, Array, dict[str, Array]]:
    """One dt of traffic and ego; returns ``(state, reward, info)`` (no observation)."""
    tr, eg, nb = state.traffic, state.ego, state.nb
    L, W, dt = p.vehicle_length, p.vehicle_width, p.dt
    lanes, slots, origin = p.lanes, p.slots_per_lane, p.lanes // 2
    lane_ids = jnp.arange(lanes)
    u = jax.random.uniform(key, (4 * lanes + 2,))
    u_head, u_v, u_v0, u_flow = jnp.split(u[: 4 * lanes], 4)
    u_dir, u_yield = u[4 * lanes], u[4 * lanes + 1]

    on = eg.phase >= CRUISE
    in_rl = eg.phase == RL

    # Action: refreshed every k-th RL step, held in between [P].
    refresh = in_rl & (eg.steps % p.k == 0)
    held = jnp.where(refresh, _clean_action(action), jnp.where(in_rl, eg.held, 0.0))
    a_lat = p.max_yaw_acc * held

    # Leaders of the other vehicles: ring predecessor, or the ego when it is ahead and its
    # body overlaps their lane (or, for a yielding lag, from the moment the gap is chosen).
    gap_r, lead_v = _ring_leaders(tr, p)
    hx, hy = kinematics.half_extents(eg.psi, L, W)
    occupied = kinematics.lanes_overlapped(eg.y, hy, lanes, p.lane_width) & on  # (lanes,)
    yields = (in_rl & eg.yielding) & (lane_ids == eg.target)[:, None] & nb.b1_mask[None, :]
    ego_gap = eg.x - 2.0 * hx - tr.x  # (lanes, slots)
    use_ego = on & (eg.x > tr.x) & (occupied[:, None] | yields) & (ego_gap < gap_r)
    gap_r = jnp.where(use_ego, ego_gap, gap_r)
    lead_v = jnp.where(use_ego, eg.v, lead_v)
    acc = jnp.where(tr.active, idm_with_params(tr.v, tr.v0, gap_r, lead_v, p), 0.0)

    # Ego longitudinal: IDM to its own-lane leader, "with adaptation" to the chosen gap.
    a_ego = idm_with_params(eg.v, eg.v0, state.leader_gap, state.leader_v, p)
    seek_gap, seek_v = gap.target_leader(nb, eg.x, eg.v, p)
    lead_gap = gap.net_gap(nb.a1_x, eg.x, L, nb.has_a1)
    adapt_gap = jnp.where(in_rl, lead_gap, seek_gap)
    # With no vehicle to adapt to (gap NO_LEADER_GAP), any finite speed gives a ~ free road.
    adapt_v = jnp.where(adapt_gap >= NO_LEADER_GAP, eg.v, jnp.where(in_rl, nb.a1_v, seek_v))
    a_adapt = idm_with_params(eg.v, eg.v0, adapt_gap, adapt_v, p)
    a_ego = jnp.where(eg.phase >= GAP, jnp.minimum(a_ego, a_adapt), a_ego)

    # Integrate: trapezoidal position update, speeds never negative.
    v_new = jnp.maximum(tr.v + acc * dt, 0.0)
    x_new = tr.x + 0.5 * (tr.v + v_new) * dt
    ev = jnp.maximum(eg.v + a_ego * dt, 0.0)
    ex, ey, epsi, eomega = kinematics.lateral_step(
        eg.x, eg.y, eg.psi, eg.omega, 0.5 * (eg.v + ev), a_lat, p.curvature, dt
    )
    active = tr.active & (x_new <= p.road_length)

    # Inflow: a lane admits its next vehicle when its timer has run out and the last entered
    # vehicle (or the ego, if it is in that lane and further back) is far enough ahead.
    slot_ids = jnp.arange(slots)
    at_tail = slot_ids[None, :] == tr.tail[:, None]
    at_last = slot_ids[None, :] == ((tr.tail - 1) % slots)[:, None]
    last_on = jnp.any(at_last & active, axis=-1)
    front = jnp.where(last_on, jnp.sum(jnp.where(at_last, x_new, 0.0), axis=-1), gap.FAR)
    front = jnp.where(occupied, jnp.minimum(front, ex), front)
    timer = tr.timer - dt
    due = (timer <= 0.0) & (front >= p.idm_s0 + tr.next_v * p.idm_time_headway + L)
    spawned_lane = due & (lane_ids == origin) & (eg.phase == WAIT) & spawn
    enter = due & ~spawned_lane & ~jnp.any(at_tail & active, axis=-1)
    entered = enter | spawned_lane
    write = at_tail & enter[:, None]
    traffic = Traffic(
        x=jnp.where(write, 0.0, x_new),
        v=jnp.where(write, tr.next_v[:, None], v_new),
        v0=jnp.where(write, tr.next_v0[:, None], tr.v0),
        active=active | write,
        tail=(tr.tail + enter) % slots,
        timer=jnp.where(entered, -jnp.log1p(-u_head) / tr.inflow, timer),
        next_v=jnp.where(entered, _between(u_v, p.entry_speed_min, p.entry_speed_max), tr.next_v),
        next_v0=jnp.where(
            entered, _between(u_v0, p.desired_speed_min, p.desired_speed_max), tr.next_v0
        ),
        inflow=tr.inflow,
    )

    # Ego phases.
    spawned = spawned_lane[origin]
    traffic = traffic.replace(
        inflow=jnp.where(spawned, _between(u_flow, p.inflow_min, p.inflow_max), tr.inflow)
    )
    y_origin = (origin + 0.5) * p.lane_width
    phase = jnp.where(spawned, CRUISE, eg.phase)
    ex = jnp.where(spawned, 0.0, ex)
    command = (phase == CRUISE) & (ex >= p.command_distance)
    side = jnp.where(u_dir < 0.5, 1, -1)
    target = origin + side
    target = jnp.where((target < 0) | (target >= lanes), origin - side, target)
    ego = Ego(
        phase=jnp.where(command, GAP, phase),
        x=ex,
        y=jnp.where(spawned, y_origin, ey),
        v=jnp.where(spawned, tr.next_v[origin], ev),
        v0=jnp.where(spawned, tr.next_v0[origin], eg.v0),
        accel=jnp.where(spawned, 0.0, a_ego),
        psi=jnp.where(spawned, 0.0, epsi),
        omega=jnp.where(spawned, 0.0, eomega),
        held=held,
        target=jnp.where(command, target, eg.target).astype(jnp.int32),
        steps=eg.steps + in_rl,
        gap_time=jnp.where(command, 0.0, eg.gap_time + dt * (eg.phase == GAP)),
        yielding=eg.yielding,
        ep_return=eg.ep_return,
    )
    nb_new, leader_gap, leader_v = _observe_lanes(traffic, ego, p)

    # Collision: the ego's (heading-aligned) bounding box against every vehicle's box.
    hx2, hy2 = kinematics.half_extents(ego.psi, L, W)
    lane_y = ((lane_ids + 0.5) * p.lane_width)[:, None]
    overlap = (jnp.abs(ego.x - hx2 - (traffic.x - 0.5 * L)) < hx2 + 0.5 * L) & (
        jnp.abs(ego.y - lane_y) < hy2 + 0.5 * W
    )
    collided = (ego.phase >= CRUISE) & ~spawned & jnp.any(traffic.active & overlap)

    # RL step: reward and end of the manoeuvre.
    offset = lateral_offset(ego, p)
    r_s, r_e, r_d = (
        jnp.where(in_rl, r, 0.0) for r in reward.reward_terms(ego.omega, a_lat, offset, collided, p)
    )
    r = r_s + r_e + r_d
    rl_reason = reward.end_reason(offset, ego.psi, ego.omega, ego.steps, collided, p)

    # Gap phase: accept the gap beside, or give up after the time or distance limit.
    looking = ego.phase == GAP
    accept = looking & gap.beside_acceptable(nb_new, ego.x, ego.v, p)
    no_gap = looking & ~accept & ((ego.gap_time >= p.gap_time_limit) | (ego.x >= p.gap_x_limit))
    reason = jnp.where(
        in_rl,
        rl_reason,
        jnp.where(collided, reward.COLLISION, jnp.where(no_gap, reward.NO_GAP, reward.NONE)),
    ).astype(jnp.int32)
    ended = reason != reward.NONE

    ep_return = jnp.where(in_rl, eg.ep_return + r, 0.0)
    ego = ego.replace(
        phase=jnp.where(ended, WAIT, jnp.where(accept, RL, ego.phase)).astype(jnp.int32),
        psi=jnp.where(accept, 0.0, ego.psi),
        omega=jnp.where(accept, 0.0, ego.omega),
        steps=jnp.where(accept, 0, ego.steps).astype(jnp.int32),
        yielding=jnp.where(accept, u_yield < p.p_yield, ego.yielding),
        ep_return=ep_return,
    )
    state = EnvState(
        traffic=traffic,
        ego=ego,
        nb=nb_new,
        leader_gap=leader_gap,
        leader_v=leader_v,
        time=state.time + 1,
    )
    info = {
        "rl_step": in_rl,
        "phase": ego.phase,
        "reason": reason,
        "lane_change": accept,
        "action": held,
        "r_s": r_s,
        "r_e": r_e,
        "r_d": r_d,
        "episode_return": ep_return,
        "episode_steps": ego.steps,
        "offset": offset,
    }
    return state, r, info


def _between(u: Array, lo: Array, hi: Array) -> Array:
    return lo + u * (hi - lo)


class LaneChangeEnv:
    """Functional env; every method is pure and jittable, and vmaps over key/state/action."""

    name = "LaneChange-v0"

    def default_params(self) -> EnvParams:
        return EnvParams()

    def observation_space(self, params: EnvParams) -> Box:
        return Box(-jnp.inf, jnp.inf, (OBS_DIM,))

    def action_space(self, params: EnvParams) -> Box:
        return Box(-1.0, 1.0, (ACT_DIM,))

    def reset(self, key: Array, params: EnvParams) -> tuple[Array, EnvState]:
        """Empty road, then ``warmup_steps`` of traffic; the ego spawns on a later step."""
        p, lanes, slots = params, params.lanes, params.slots_per_lane
        k_init, k_warm = jax.random.split(key)
        u = jax.random.uniform(k_init, (4, lanes))
        zeros = jnp.zeros((lanes, slots), jnp.float32)
        inflow = _between(u[3], p.inflow_min, p.inflow_max)
        traffic = Traffic(
            x=zeros,
            v=zeros,
            v0=zeros + p.desired_speed_max,
            active=jnp.zeros((lanes, slots), bool),
            tail=jnp.zeros(lanes, jnp.int32),
            timer=-jnp.log1p(-u[0]) / inflow,
            next_v=_between(u[1], p.entry_speed_min, p.entry_speed_max),
            next_v0=_between(u[2], p.desired_speed_min, p.desired_speed_max),
            inflow=inflow,
        )
        f0 = jnp.float32(0.0)
        ego = Ego(
            phase=jnp.int32(WAIT),
            x=f0,
            y=jnp.float32((lanes // 2 + 0.5) * p.lane_width),
            v=f0,
            v0=f0 + p.desired_speed_max,
            accel=f0,
            psi=f0,
            omega=f0,
            held=f0,
            target=jnp.int32(lanes // 2),
            steps=jnp.int32(0),
            gap_time=f0,
            yielding=jnp.bool_(False),
            ep_return=f0,
        )
        nb, leader_gap, leader_v = _observe_lanes(traffic, ego, p)
        state = EnvState(traffic, ego, nb, leader_gap, leader_v, jnp.int32(0))

        def warm(s: EnvState, k: Array) -> tuple[EnvState, None]:
            return _advance(k, s, jnp.zeros(ACT_DIM), p, spawn=False)[0], None

        state, _ = jax.lax.scan(warm, state, jax.random.split(k_warm, p.warmup_steps))
        return observation(state, p), state.replace(time=jnp.int32(0))

    def step(
        self, key: Array, state: EnvState, action: Array, params: EnvParams
    ) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
        """Advance one dt. ``terminated``/``truncated`` refer to the RL manoeuvre (a timeout
        truncates unless ``params.terminal_timeout``); ``info`` has the reward terms, phase
        and ``reason`` codes of ``jaxlc.reward.REASONS``."""
        state, r, info = _advance(key, state, action, params, spawn=True)
        reason = info["reason"]
        rl = info["rl_step"]
        timeout = rl & (reason == reward.TIMEOUT)
        terminated = rl & (
            (reason == reward.SUCCESS)
            | (reason == reward.OUT_OF_BOUNDS)
            | (reason == reward.COLLISION)
        )
        terminated = terminated | (timeout & params.terminal_timeout)
        truncated = timeout & ~params.terminal_timeout
        return observation(state, params), state, r, terminated, truncated, info


def make(config: Config | EnvConfig | None = None, k: int = 1) -> tuple[LaneChangeEnv, EnvParams]:
    """``env, params = jaxlc.make()``: the paper's defaults, or those of ``config``."""
    if config is None:
        from jaxlc import config as config_mod

        config = config_mod.load()
    if isinstance(config, Config):
        return LaneChangeEnv(), EnvParams.from_config(config.env, config.ddpg.gamma, k)
    return LaneChangeEnv(), EnvParams.from_config(config, k=k)
