"""The lane-change environment: a functional, gymnax-style API over a batched traffic sim.

    env, params = jaxlc.make()
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

One env is one highway: ``lanes`` lanes of ``road_length`` metres, each with
``slots_per_lane`` vehicle slots used as a ring buffer in entry order. Only the ego changes
lanes, so vehicles of a lane never pass each other and a vehicle's leader is simply the slot
written before it: no search (see ``_ring_leaders``). The ego is kept apart from the slots.

The road is a band of concentric arcs of curvature kappa (0: straight; a constant, or drawn
per episode), and everything runs in its frame (``kinematics``): x is s along the road's
centre line, y across it; a lane's gaps are metres along its own centre line
(``lane_scales``), and every vehicle follows its lane.

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

Observation (``OBS_DIM`` = 14, normalised): the table ``jaxlc.sim.observation.LAYOUT`` gives each
entry's name, index, scale and meaning (speed, acceleration, heading, yaw rate, offset from the
target lane, held action, manoeuvre time, curvature, then gap and dv to the target lane's
leader and follower and to the leader in the ego's current lane); ``MIRROR_SIGNS`` reflects an
observation across the road's axis.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.config import Config, DDPGConfig, EnvConfig
from jaxlc.sim import gap, kinematics, reward
from jaxlc.sim import observation as obs_layout
from jaxlc.sim.idm import NO_LEADER_GAP, idm_with_params
from jaxlc.sim.observation import GAP_CLIP, MIRROR_SIGNS, OBS_DIM  # noqa: F401 (re-exported)

WAIT, CRUISE, GAP, RL = 0, 1, 2, 3
PHASES = ("wait", "cruise", "gap", "rl")
ACT_DIM = 1
KMH = 1.0 / 3.6


# The defaults are written once, in jaxlc/config.py (and configs/default.toml, which a test
# holds equal to them); EnvParams takes them over in SI units.
_C = EnvConfig()
_WARMUP_STEPS = int(round(_C.warmup_time / _C.dt))


@flax.struct.dataclass
class EnvParams:
    """Simulator parameters in SI units (speeds m/s, inflow veh/s); the defaults are
    ``EnvConfig()``'s, converted.

    Static fields (``pytree_node=False``) fix array shapes and loop lengths; every other
    field is traced, so models with different values (e.g. the action-update step ``k``)
    can share one compiled program under ``vmap``.
    """

    lanes: int = flax.struct.field(pytree_node=False, default=_C.lanes)
    slots_per_lane: int = flax.struct.field(pytree_node=False, default=_C.slots_per_lane)
    warmup_steps: int = flax.struct.field(pytree_node=False, default=_WARMUP_STEPS)
    road_length: float = _C.road_length
    lane_width: float = _C.lane_width
    # The road's curvature (1/m, > 0 bends toward +y): the constant ``curvature``, or, when
    # ``curvature_drawn`` (static: it adds a leaf to the state), one drawn per episode from
    # U(curvature_min, curvature_max) as the ego spawns and kept in ``EnvState.curvature``.
    curvature: float = 0.0
    curvature_min: float = 0.0
    curvature_max: float = 0.0
    curvature_drawn: bool = flax.struct.field(pytree_node=False, default=False)
    dt: float = _C.dt
    vehicle_length: float = _C.vehicle_length
    vehicle_width: float = _C.vehicle_width
    entry_speed_min: float = _C.entry_speed_min * KMH
    entry_speed_max: float = _C.entry_speed_max * KMH
    desired_speed_min: float = _C.desired_speed_min * KMH
    desired_speed_max: float = _C.desired_speed_max * KMH
    inflow_min: float = _C.inflow_min / 3600.0
    inflow_max: float = _C.inflow_max / 3600.0
    idm_a_max: float = _C.idm_a_max
    idm_b: float = _C.idm_b
    idm_time_headway: float = _C.idm_time_headway
    idm_s0: float = _C.idm_s0
    idm_delta: float = _C.idm_delta
    idm_b_max: float = _C.idm_b_max
    p_yield: float = _C.p_yield
    command_distance: float = _C.command_distance
    gap_time_limit: float = _C.gap_time_limit
    gap_x_limit: float = _C.gap_x_limit
    gap_time_headway: float = _C.gap_time_headway
    b_safe: float = _C.b_safe
    gap_min_ttc: float = _C.gap_min_ttc
    max_yaw_acc: float = _C.max_yaw_acc
    manoeuvre_time_limit: float = _C.manoeuvre_time_limit
    terminal_timeout: bool = _C.terminal_timeout
    border: float = _C.border
    success_offset: float = _C.success_offset
    success_heading: float = _C.success_heading
    success_yaw_rate: float = _C.success_yaw_rate
    w1: float = _C.w1
    w2: float = _C.w2
    w3: float = _C.w3
    w4: float = _C.w4
    reward_scale: float = _C.reward_scale
    offset_obs_scale: float = _C.offset_obs_scale
    gamma: float = DDPGConfig().gamma
    k: int = 1

    @classmethod
    def from_config(
        cls, env: EnvConfig, gamma: float = DDPGConfig().gamma, k: int = 1
    ) -> EnvParams:
        """Convert a validated ``EnvConfig`` (km/h, veh/h) to SI params."""
        values = {f: getattr(env, f) for f in cls.__dataclass_fields__ if hasattr(env, f)}
        for f in ("entry_speed_min", "entry_speed_max", "desired_speed_min", "desired_speed_max"):
            values[f] = values[f] * KMH
        values["inflow_min"] = env.inflow_min / 3600.0
        values["inflow_max"] = env.inflow_max / 3600.0
        values["warmup_steps"] = int(round(env.warmup_time / env.dt))  # as _WARMUP_STEPS
        lo, hi = curvature_range(env.curvature)
        values["curvature"] = lo if lo == hi else 0.5 * (lo + hi)
        values["curvature_min"], values["curvature_max"] = lo, hi
        values["curvature_drawn"] = lo < hi
        return cls(**values, gamma=gamma, k=k)


def curvature_range(value: float | tuple[float, float]) -> tuple[float, float]:
    """``(min, max)`` of a config's ``env.curvature``: a number (a constant road) or a range."""
    if isinstance(value, tuple | list):
        return float(value[0]), float(value[1])
    return float(value), float(value)


@flax.struct.dataclass
class Traffic:
    """Vehicles other than the ego; lane arrays are ``(lanes, slots)``, ring buffers."""

    x: Array  # (lanes, slots) front bumper, s along the road's centre line, m
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
    x: Array  # () front bumper, s along the road's centre line, m
    y: Array  # () lateral position of the body's centre line, m
    v: Array  # () m/s
    v0: Array  # () desired speed, m/s
    accel: Array  # () last longitudinal acceleration, m/s^2
    psi: Array  # () heading relative to the lane's direction, rad
    omega: Array  # () yaw rate (inertial: kappa_d*v holds a lane), rad/s
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
    # () the episode's road curvature when drawn per episode (``params.curvature_drawn``);
    # None (no leaf) on a road of constant curvature, whose state is a straight road's.
    curvature: Array | None = None


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


# --- the road frame ---------------------------------------------------------------------
# Positions are Frenet (``kinematics``): x = s along the road's centre line (the reference
# line, at y = lanes*W/2), y across it. A lane's net gaps are metres along its own centre
# line: s times its ``lane_scale`` (exactly 1 on a straight road, so there every product below
# is the straight road's number to the bit).


def road_curvature(state: EnvState, p: EnvParams) -> Array:
    """``()`` curvature of the road in ``state``: the episode's draw, or the constant."""
    return jnp.asarray(p.curvature if state.curvature is None else state.curvature)


def reference_y(p: EnvParams) -> Array:
    """y of the road's centre line, the reference line of the Frenet frame."""
    return 0.5 * p.lanes * p.lane_width


def lane_offset(lane: Array, p: EnvParams) -> Array:
    """Signed offset d of lane ``lane``'s centre line from the reference line (any shape)."""
    return (lane + 0.5) * p.lane_width - reference_y(p)


def lane_scales(kappa: Array, p: EnvParams) -> Array:
    """``(lanes,)`` metres along each lane's centre line per metre of s."""
    return kinematics.lane_scale(kappa, lane_offset(jnp.arange(p.lanes), p))


def ego_yaw_rate(eg: Ego, kappa: Array, p: EnvParams) -> Array:
    """``()`` the ego's yaw rate relative to its lane's (``kinematics.relative_yaw_rate``): what
    the success test and the reward's comfort term read; ``eg.omega`` on a straight road."""
    return kinematics.relative_yaw_rate(eg.omega, eg.psi, eg.v, kappa, eg.y - reference_y(p))


def lane_keeping_yaw_rate(eg: Ego, v: Array, kappa: Array, p: EnvParams) -> Array:
    """``()`` the yaw rate that holds the ego's line at speed ``v`` (psi = 0): kappa_d*v."""
    return kinematics.path_curvature(kappa, eg.y - reference_y(p)) * v


def _ring_leaders(tr: Traffic, p: EnvParams, scale: Array) -> tuple[Array, Array]:
    """Net gap and speed of each slot's leader: the slot written just before it, when that
    slot is occupied and ahead (a full ring's oldest slot has the newest behind it). ``scale``
    ``(lanes,)`` is ``lane_scales``: the gap is metres along the lane."""
    px, pv, pa = (jnp.roll(a, 1, axis=-1) for a in (tr.x, tr.v, tr.active))
    has = pa & (px > tr.x)
    c = scale[:, None]
    gap_m = px * c - p.vehicle_length - tr.x * c
    return jnp.where(has, gap_m, NO_LEADER_GAP), jnp.where(has, pv, tr.v)


def _lane_row(a: Array, lane: Array, lanes: int) -> Array:
    """``a[lane]`` for a traced lane index, as a masked sum (cheaper than a gather under vmap)."""
    sel = (jnp.arange(lanes) == lane)[:, None]
    if a.dtype == jnp.bool_:
        return jnp.any(sel & a, axis=0)
    return jnp.sum(jnp.where(sel, a, 0), axis=0)


def current_lane(eg: Ego, p: EnvParams) -> Array:
    """Index of the lane that holds the ego's centre (the origin lane until it crosses)."""
    return jnp.clip(jnp.floor(eg.y / p.lane_width), 0, p.lanes - 1).astype(jnp.int32)


def _observe_lanes(
    tr: Traffic, eg: Ego, p: EnvParams, kappa: Array | None = None
) -> tuple[gap.Neighbours, Array, Array]:
    """Target-lane neighbours (positions in s) and the net gap (metres along the lane) and
    speed of the leader in the ego's current lane (meaningless in WAIT)."""
    kappa = p.curvature if kappa is None else kappa
    row = lambda a: _lane_row(a, eg.target, p.lanes)  # noqa: E731
    nb = gap.neighbours(row(tr.x), row(tr.v), row(tr.v0), row(tr.active), eg.x)
    cur = current_lane(eg, p)
    cx, cv = _lane_row(tr.x, cur, p.lanes), _lane_row(tr.v, cur, p.lanes)  # (slots,)
    ahead = _lane_row(tr.active, cur, p.lanes) & (cx > eg.x)
    lx = jnp.min(jnp.where(ahead, cx, gap.FAR))
    lv = jnp.max(jnp.where(ahead & (cx == lx), cv, -gap.FAR))
    has = jnp.any(ahead)
    c = kinematics.lane_scale(kappa, lane_offset(cur, p))
    return nb, gap.net_gap(lx * c, eg.x * c, p.vehicle_length, has), jnp.where(has, lv, eg.v)


def target_frame(nb: gap.Neighbours, eg: Ego, kappa: Array, p: EnvParams):
    """``(nb, x)``: the target lane's neighbours and the ego's x in metres along the target
    lane's centre line (``gap``'s functions measure gaps in these)."""
    c = kinematics.lane_scale(kappa, lane_offset(eg.target, p))
    return gap.scaled(nb, c), eg.x * c


def target_gaps(state: EnvState, p: EnvParams) -> tuple[Array, Array]:
    """``(lead_gap, lag_gap)``: net gaps (m along the target lane) from the ego to the target
    lane's lead and lag vehicles; meaningless where ``state.nb.has_a1``/``has_b1`` is False."""
    nb, x = target_frame(state.nb, state.ego, road_curvature(state, p), p)
    return nb.a1_x - p.vehicle_length - x, x - p.vehicle_length - nb.b1_x


def lateral_offset(eg: Ego, p: EnvParams) -> Array:
    """Signed offset of the ego from the target lane's centre line, m.

    Measured from the origin lane's centre so that it is exactly +-W when the manoeuvre
    starts (``5.55 - 1.85`` rounds above 3.7 in float32 and would end it at once)."""
    origin = p.lanes // 2
    return (eg.y - (origin + 0.5) * p.lane_width) - (eg.target - origin) * p.lane_width


def observation(state: EnvState, p: EnvParams) -> Array:
    """``(OBS_DIM,)`` normalised observation of ``state``: the entries of
    ``jaxlc.sim.observation.LAYOUT``, each raw value divided by its scale."""
    eg, nb = state.ego, state.nb

    def gap_m(g: Array, present: Array) -> Array:
        return jnp.where(present, jnp.clip(g, *GAP_CLIP), GAP_CLIP[1])

    def dv(v_other: Array, present: Array) -> Array:
        return jnp.where(present, v_other - eg.v, 0.0)

    has_leader = state.leader_gap < NO_LEADER_GAP
    lead_gap, lag_gap = target_gaps(state, p)
    raw = {
        "v": eg.v,
        "accel": eg.accel,
        "psi": eg.psi,
        "omega": eg.omega,
        "offset": lateral_offset(eg, p),
        "held": eg.held,
        # A truncated timeout is bootstrapped, so the time must not be observed: values at
        # time = limit are never learned as current states (Pardo et al., 2018).
        "time": jnp.where(p.terminal_timeout, eg.steps * p.dt, 0.0),
        "curvature": road_curvature(state, p) * jnp.ones_like(eg.v),
        "lead_gap": gap_m(lead_gap, nb.has_a1),
        "lead_dv": dv(nb.a1_v, nb.has_a1),
        "lag_gap": gap_m(lag_gap, nb.has_b1),
        "lag_dv": dv(nb.b1_v, nb.has_b1),
        "own_gap": gap_m(state.leader_gap, has_leader),
        "own_dv": dv(state.leader_v, has_leader),
    }
    obs = jnp.stack([raw[e.name] / obs_layout.scale(e.name, p) for e in obs_layout.LAYOUT])
    return obs.astype(jnp.float32)


def _clean_action(action: Array) -> Array:
    """Any action, NaN and inf included, becomes a finite value in [-1, 1]."""
    a = jnp.reshape(action, (-1,))[0].astype(jnp.float32)
    return jnp.clip(jnp.nan_to_num(a, nan=0.0, posinf=1.0, neginf=-1.0), -1.0, 1.0)


# --- the highway step, phase by phase ------------------------------------------------------
# ``_advance`` calls these in order; each is pure and reads only what its arguments hold.


class Draws(NamedTuple):
    """The step's uniform random numbers, one draw per use."""

    headway: Array  # (lanes,) time to the entry after the next one, via -log(1-u)/inflow
    entry_v: Array  # (lanes,) entry speed of the next entrant
    entry_v0: Array  # (lanes,) desired speed of the next entrant
    inflow: Array  # (lanes,) inflow of the episode a spawned ego starts
    side: Array  # () left (< 0.5) or right command
    yields: Array  # () whether the lag yields (< p_yield) once the gap is accepted
    curvature: Array  # () road curvature of the episode a spawned ego starts (if drawn)

    @classmethod
    def draw(cls, key: Array, lanes: int) -> Draws:
        # The curvature's number comes last: threefry draws are counter-based per element
        # (jax_threefry_partitionable), so the others are those of a draw without it.
        u = jax.random.uniform(key, (4 * lanes + 3,))
        headway, entry_v, entry_v0, inflow = jnp.split(u[: 4 * lanes], 4)
        return cls(headway, entry_v, entry_v0, inflow, *u[4 * lanes :])


class Motion(NamedTuple):
    """Every vehicle one dt later, before inflow and phase changes."""

    x: Array  # (lanes, slots) traffic front bumpers, m
    v: Array  # (lanes, slots) traffic speeds, m/s
    active: Array  # (lanes, slots) still on the road
    ego_x: Array  # ()
    ego_y: Array  # ()
    ego_v: Array  # ()
    ego_psi: Array  # ()
    ego_omega: Array  # ()


def held_action(ego: Ego, action: Array, p: EnvParams) -> Array:
    """``()`` action executed this step: refreshed every k-th RL step, held in between [P],
    0 outside the RL phase."""
    in_rl = ego.phase == RL
    refresh = in_rl & (ego.steps % p.k == 0)
    return jnp.where(refresh, _clean_action(action), jnp.where(in_rl, ego.held, 0.0))


def ego_lanes(ego: Ego, p: EnvParams) -> Array:
    """``(lanes,)`` bool, lanes the ego's body overlaps (none while no ego is on the road)."""
    _, hy = kinematics.half_extents(ego.psi, p.vehicle_length, p.vehicle_width)
    return kinematics.lanes_overlapped(ego.y, hy, p.lanes, p.lane_width) & (ego.phase >= CRUISE)


def traffic_accel(state: EnvState, p: EnvParams) -> Array:
    """``(lanes, slots)`` IDM acceleration of every vehicle (0 for empty slots).

    A vehicle's leader is its ring predecessor, or the ego when the ego is ahead and its body
    overlaps the vehicle's lane (or, for a yielding lag, from the moment the gap is chosen).
    Gaps are metres along the vehicle's lane."""
    tr, eg, nb = state.traffic, state.ego, state.nb
    on, in_rl = eg.phase >= CRUISE, eg.phase == RL
    c = lane_scales(road_curvature(state, p), p)  # (lanes,)
    gap_r, lead_v = _ring_leaders(tr, p, c)
    hx, _ = kinematics.half_extents(eg.psi, p.vehicle_length, p.vehicle_width)
    target = jnp.arange(p.lanes) == eg.target
    yields = (in_rl & eg.yielding) & target[:, None] & nb.b1_mask[None, :]
    ego_gap = eg.x * c[:, None] - 2.0 * hx - tr.x * c[:, None]  # (lanes, slots)
    use_ego = on & (eg.x > tr.x) & (ego_lanes(eg, p)[:, None] | yields) & (ego_gap < gap_r)
    gap_r = jnp.where(use_ego, ego_gap, gap_r)
    lead_v = jnp.where(use_ego, eg.v, lead_v)
    return jnp.where(tr.active, idm_with_params(tr.v, tr.v0, gap_r, lead_v, p), 0.0)


def ego_accel(state: EnvState, p: EnvParams) -> Array:
    """``()`` IDM acceleration of the ego toward its own-lane leader, "with adaptation" to the
    chosen gap once it looks for one: the lower of the two."""
    eg = state.ego
    in_rl = eg.phase == RL
    nb, x = target_frame(state.nb, eg, road_curvature(state, p), p)  # m along the target lane
    a_own = idm_with_params(eg.v, eg.v0, state.leader_gap, state.leader_v, p)
    seek_gap, seek_v = gap.target_leader(nb, x, eg.v, p)
    lead_gap = gap.net_gap(nb.a1_x, x, p.vehicle_length, nb.has_a1)
    adapt_gap = jnp.where(in_rl, lead_gap, seek_gap)
    # With no vehicle to adapt to (gap NO_LEADER_GAP), any finite speed gives a ~ free road.
    adapt_v = jnp.where(adapt_gap >= NO_LEADER_GAP, eg.v, jnp.where(in_rl, nb.a1_v, seek_v))
    a_adapt = idm_with_params(eg.v, eg.v0, adapt_gap, adapt_v, p)
    return jnp.where(eg.phase >= GAP, jnp.minimum(a_own, a_adapt), a_own)


def move(
    tr: Traffic,
    eg: Ego,
    acc: Array,
    a_ego: Array,
    a_lat: Array,
    p: EnvParams,
    kappa: Array | None = None,
) -> Motion:
    """Integrate one dt: trapezoidal positions along each lane (s advances by the distance
    over ``lane_scales``), speeds never negative; the ego's lateral state by
    ``kinematics.lateral_step``. Vehicles past the road's end (s > road_length) leave it.

    Before the RL phase (CRUISE, GAP) the ego holds its lane: psi = 0 and omega = kappa_d*v,
    so its y stays put on any road (on a straight one both are 0 already). In WAIT the ego is
    off the road; it coasts as on a straight road, so its numbers stay finite."""
    kappa = p.curvature if kappa is None else kappa
    dt = p.dt
    v_new = jnp.maximum(tr.v + acc * dt, 0.0)
    x_new = tr.x + 0.5 * (tr.v + v_new) * dt / lane_scales(kappa, p)[:, None]
    ev = jnp.maximum(eg.v + a_ego * dt, 0.0)
    v_ego = 0.5 * (eg.v + ev)
    k_ego = jnp.where(eg.phase == WAIT, 0.0, kappa)
    holds = (eg.phase == CRUISE) | (eg.phase == GAP)
    psi = jnp.where(holds, 0.0, eg.psi)
    omega = jnp.where(holds, lane_keeping_yaw_rate(eg, v_ego, k_ego, p), eg.omega)
    ex, ey, epsi, eomega = kinematics.lateral_step(
        eg.x, eg.y, psi, omega, v_ego, a_lat, k_ego, dt, reference_y(p)
    )
    active = tr.active & (x_new <= p.road_length)
    return Motion(x_new, v_new, active, ex, ey, ev, epsi, eomega)


def inflow(
    tr: Traffic,
    m: Motion,
    occupied: Array,
    can_spawn: Array,
    u: Draws,
    p: EnvParams,
    kappa: Array | None = None,
) -> tuple[Traffic, Array]:
    """New vehicles at x = 0. Returns ``(traffic, spawned)``, ``spawned`` () bool.

    A lane admits its next vehicle when its timer has run out and the last entered vehicle
    (or the ego, if it is in that lane and further back) is far enough ahead. When
    ``can_spawn`` (no ego, spawning on), the middle lane's entrant becomes the ego instead of
    a slot, and the episode it starts draws the lanes' inflow anew."""
    lanes, slots, origin = p.lanes, p.slots_per_lane, p.lanes // 2
    lane_ids, slot_ids = jnp.arange(lanes), jnp.arange(slots)
    at_tail = slot_ids[None, :] == tr.tail[:, None]
    at_last = slot_ids[None, :] == ((tr.tail - 1) % slots)[:, None]
    last_on = jnp.any(at_last & m.active, axis=-1)
    front = jnp.where(last_on, jnp.sum(jnp.where(at_last, m.x, 0.0), axis=-1), gap.FAR)
    front = jnp.where(occupied, jnp.minimum(front, m.ego_x), front)
    front = front * lane_scales(p.curvature if kappa is None else kappa, p)  # m along the lane
    timer = tr.timer - p.dt
    due = (timer <= 0.0) & (front >= p.idm_s0 + tr.next_v * p.idm_time_headway + p.vehicle_length)
    spawned_lane = due & (lane_ids == origin) & can_spawn
    enter = due & ~spawned_lane & ~jnp.any(at_tail & m.active, axis=-1)
    entered = enter | spawned_lane
    write = at_tail & enter[:, None]
    spawned = spawned_lane[origin]
    traffic = Traffic(
        x=jnp.where(write, 0.0, m.x),
        v=jnp.where(write, tr.next_v[:, None], m.v),
        v0=jnp.where(write, tr.next_v0[:, None], tr.v0),
        active=m.active | write,
        tail=(tr.tail + enter) % slots,
        timer=jnp.where(entered, -jnp.log1p(-u.headway) / tr.inflow, timer),
        next_v=jnp.where(
            entered, _between(u.entry_v, p.entry_speed_min, p.entry_speed_max), tr.next_v
        ),
        next_v0=jnp.where(
            entered, _between(u.entry_v0, p.desired_speed_min, p.desired_speed_max), tr.next_v0
        ),
        inflow=jnp.where(spawned, _between(u.inflow, p.inflow_min, p.inflow_max), tr.inflow),
    )
    return traffic, spawned


def ego_phase(
    eg: Ego,
    m: Motion,
    a_ego: Array,
    held: Array,
    spawned: Array,
    tr: Traffic,
    u: Draws,
    p: EnvParams,
) -> Ego:
    """The ego after the move: a spawned ego starts CRUISE at x = 0 in the middle lane with the
    entrant's speeds (``tr``, the traffic before inflow); a cruising ego that has travelled
    ``command_distance`` gets a left or right command (toward the road when the lane beside is
    missing) and enters GAP. RL steps and gap-search time are counted here."""
    origin = p.lanes // 2
    in_rl = eg.phase == RL
    phase = jnp.where(spawned, CRUISE, eg.phase)
    ex = jnp.where(spawned, 0.0, m.ego_x)
    command = (phase == CRUISE) & (ex >= p.command_distance)
    side = jnp.where(u.side < 0.5, 1, -1)
    target = origin + side
    target = jnp.where((target < 0) | (target >= p.lanes), origin - side, target)
    return Ego(
        phase=jnp.where(command, GAP, phase),
        x=ex,
        y=jnp.where(spawned, (origin + 0.5) * p.lane_width, m.ego_y),
        v=jnp.where(spawned, tr.next_v[origin], m.ego_v),
        v0=jnp.where(spawned, tr.next_v0[origin], eg.v0),
        accel=jnp.where(spawned, 0.0, a_ego),
        psi=jnp.where(spawned, 0.0, m.ego_psi),
        omega=jnp.where(spawned, 0.0, m.ego_omega),
        held=held,
        target=jnp.where(command, target, eg.target).astype(jnp.int32),
        steps=eg.steps + in_rl,
        gap_time=jnp.where(command, 0.0, eg.gap_time + p.dt * (eg.phase == GAP)),
        yielding=eg.yielding,
        ep_return=eg.ep_return,
    )


def overlaps(traffic: Traffic, ego: Ego, p: EnvParams, kappa: Array | None = None) -> Array:
    """``(lanes, slots)`` bool: the vehicles whose box the ego's heading-aligned bounding box
    overlaps (whatever the ego's phase); lengthwise in metres along each lane."""
    L, W = p.vehicle_length, p.vehicle_width
    c = lane_scales(p.curvature if kappa is None else kappa, p)[:, None]
    hx, hy = kinematics.half_extents(ego.psi, L, W)
    lane_y = ((jnp.arange(p.lanes) + 0.5) * p.lane_width)[:, None]
    overlap = (jnp.abs(ego.x * c - hx - (traffic.x * c - 0.5 * L)) < hx + 0.5 * L) & (
        jnp.abs(ego.y - lane_y) < hy + 0.5 * W
    )
    return traffic.active & overlap


def collided(
    traffic: Traffic, ego: Ego, spawned: Array, p: EnvParams, kappa: Array | None = None
) -> Array:
    """``()`` bool: the ego's box overlaps a vehicle's box (a just spawned ego, at the road's
    start, is not checked)."""
    return (ego.phase >= CRUISE) & ~spawned & jnp.any(overlaps(traffic, ego, p, kappa))


def gap_decision(
    ego: Ego, nb: gap.Neighbours, p: EnvParams, kappa: Array | None = None
) -> tuple[Array, Array]:
    """``(accept, no_gap)``: in GAP, accept the gap beside the ego, or give up once the time or
    distance limit is reached without one (x, the limit, in s)."""
    looking = ego.phase == GAP
    nb_m, x_m = target_frame(nb, ego, p.curvature if kappa is None else kappa, p)
    accept = looking & gap.beside_acceptable(nb_m, x_m, ego.v, p)
    no_gap = looking & ~accept & ((ego.gap_time >= p.gap_time_limit) | (ego.x >= p.gap_x_limit))
    return accept, no_gap


def end_reason(in_rl: Array, rl_reason: Array, crashed: Array, no_gap: Array) -> Array:
    """``()`` int32 reason code of ``jaxlc.sim.reward.REASONS``: the RL manoeuvre's own, else a
    collision or no gap before it, else NONE."""
    before_rl = jnp.where(crashed, reward.COLLISION, jnp.where(no_gap, reward.NO_GAP, reward.NONE))
    return jnp.where(in_rl, rl_reason, before_rl).astype(jnp.int32)


def _advance(
    key: Array, state: EnvState, action: Array, p: EnvParams, spawn: bool
) -> tuple[EnvState, Array, dict[str, Array]]:
    """One dt of traffic and ego; returns ``(state, reward, info)`` (no observation)."""
    tr, eg = state.traffic, state.ego
    u = Draws.draw(key, p.lanes)
    kappa = road_curvature(state, p)
    in_rl = eg.phase == RL
    held = held_action(eg, action, p)
    a_lat = p.max_yaw_acc * held
    a_ego = ego_accel(state, p)
    m = move(tr, eg, traffic_accel(state, p), a_ego, a_lat, p, kappa)
    occupied = ego_lanes(eg, p)
    traffic, spawned = inflow(tr, m, occupied, (eg.phase == WAIT) & spawn, u, p, kappa)
    ego = ego_phase(eg, m, a_ego, held, spawned, tr, u, p)
    if p.curvature_drawn:  # a new episode, a new road (the traffic keeps its s and lanes)
        kappa = jnp.where(spawned, _between(u.curvature, p.curvature_min, p.curvature_max), kappa)
    nb, leader_gap, leader_v = _observe_lanes(traffic, ego, p, kappa)
    crashed = collided(traffic, ego, spawned, p, kappa)

    offset = lateral_offset(ego, p)
    # Comfort and success read the yaw rate relative to the lane's (= omega when straight).
    yaw_rate = ego_yaw_rate(ego, kappa, p)
    terms = reward.reward_terms(yaw_rate, a_lat, offset, crashed, p)
    r_s, r_e, r_d = (jnp.where(in_rl, r, 0.0) for r in terms)
    r = r_s + r_e + r_d
    rl_reason = reward.end_reason(offset, ego.psi, yaw_rate, ego.steps, crashed, p)
    accept, no_gap = gap_decision(ego, nb, p, kappa)
    reason = end_reason(in_rl, rl_reason, crashed, no_gap)
    ended = reason != reward.NONE

    ep_return = jnp.where(in_rl, eg.ep_return + r, 0.0)
    ego = ego.replace(
        phase=jnp.where(ended, WAIT, jnp.where(accept, RL, ego.phase)).astype(jnp.int32),
        # The RL phase starts on the lane's line: no heading, the lane-holding yaw rate.
        psi=jnp.where(accept, 0.0, ego.psi),
        omega=jnp.where(accept, lane_keeping_yaw_rate(ego, ego.v, kappa, p), ego.omega),
        steps=jnp.where(accept, 0, ego.steps).astype(jnp.int32),
        yielding=jnp.where(accept, u.yields < p.p_yield, ego.yielding),
        ep_return=ep_return,
    )
    road = kappa if p.curvature_drawn else None
    state = EnvState(traffic, ego, nb, leader_gap, leader_v, state.time + 1, road)
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
        road = None
        if p.curvature_drawn:  # its own key: a constant road's draws are left as they were
            u_road = jax.random.uniform(jax.random.fold_in(k_init, 1))
            road = _between(u_road, p.curvature_min, p.curvature_max)
        nb, leader_gap, leader_v = _observe_lanes(
            traffic, ego, p, p.curvature if road is None else road
        )
        state = EnvState(traffic, ego, nb, leader_gap, leader_v, jnp.int32(0), road)

        def warm(s: EnvState, k: Array) -> tuple[EnvState, None]:
            return _advance(k, s, jnp.zeros(ACT_DIM), p, spawn=False)[0], None

        state, _ = jax.lax.scan(warm, state, jax.random.split(k_warm, p.warmup_steps))
        return observation(state, p), state.replace(time=jnp.int32(0))

    def step(
        self, key: Array, state: EnvState, action: Array, params: EnvParams
    ) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
        """Advance one dt. ``terminated``/``truncated`` refer to the RL manoeuvre (a timeout
        truncates unless ``params.terminal_timeout``); ``info`` has the reward terms, phase
        and ``reason`` codes of ``jaxlc.sim.reward.REASONS``."""
        state, r, info = _advance(key, state, action, params, spawn=True)
        reason = info["reason"]
        rl = info["rl_step"]
        timeout = rl & (reason == reward.TIMEOUT)
        terminated = rl & (
            (reason == reward.SUCCESS)
            | (reason == reward.OUT_OF_BOUNDS)
            | (reason == reward.COLLISION)
        )
        # A Python bool here (params compiled in as constants) would make ~ give -1, an int.
        terminal_timeout = jnp.asarray(params.terminal_timeout, bool)
        terminated = terminated | (timeout & terminal_timeout)
        truncated = timeout & ~terminal_timeout
        return observation(state, params), state, r, terminated, truncated, info


def make(config: Config | EnvConfig | None = None, k: int = 1) -> tuple[LaneChangeEnv, EnvParams]:
    """``env, params = jaxlc.make()``: the paper's defaults, or those of ``config``."""
    if config is None:
        from jaxlc import config as config_mod

        config = config_mod.load()
    if isinstance(config, Config):
        return LaneChangeEnv(), EnvParams.from_config(config.env, config.ddpg.gamma, k)
    return LaneChangeEnv(), EnvParams.from_config(config, k=k)
