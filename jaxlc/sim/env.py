"""The lane-change environment: a functional, gymnax-style API over a batched traffic sim.

    env, params = jaxlc.make()
    obs, state = env.reset(key, params)
    obs, state, reward, terminated, truncated, info = env.step(key, state, action, params)

One env is one highway: ``lanes`` lanes of ``road_length`` metres, each with
``slots_per_lane`` vehicle slots used as a ring buffer in entry order (``traffic``); the ego
is kept apart from the slots (``ego``). The road is a band of concentric arcs of curvature
kappa (0: straight; a constant, or drawn per episode), and everything runs in its frame
(``road``, ``kinematics``).

This module is the step alone; each concept has its own module: ``params`` (EnvParams),
``state`` (the state types, phases, draws), ``road`` (lanes, centre lines, scales),
``traffic`` (the traffic's own step: leaders, IDM, lane changes, inflow, braking events),
``ego`` (action, acceleration, phases, gap decision), ``motion`` (one dt of integration),
``collision``, ``reward`` (terms and why an episode ends) and ``observation``.

The ego goes through four phases (``info["phase"]``, ``ego.py``): WAIT, CRUISE, GAP, then RL,
where the action steers it; only RL steps are transitions (``info["rl_step"]``). When an
episode ends the ego leaves the road and the env goes back to WAIT on the same step
(auto-reset); traffic keeps flowing, so no warm-up is needed between episodes. The returned
``obs`` is the observation after the step: on the step an episode ends it is the terminal
observation, which is what a learner bootstraps from.

Action: ``(1,)`` in [-1, 1], the yaw acceleration over ``max_yaw_acc``; with
``env.longitudinal = "policy"`` ``(2,)`` (``action_dim``), the second entry adding
``long_acc_bound`` times it to the ego's IDM acceleration in the RL phase (``ego.ego_accel``).

Observation: ``OBS_DIM`` = 14 normalised entries, the table ``observation.LAYOUT``. Params
may be closed over or passed traced (and vmapped: one program for a batch of drawn tasks);
both give the same rollout, its reals to float32 rounding (``tests/test_rollout_golden.py``).
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.config import Config, EnvConfig
from jaxlc.sim import braking, mobil, reward
from jaxlc.sim import traffic as traffic_mod
from jaxlc.sim.collision import collided
from jaxlc.sim.controller import executed_action
from jaxlc.sim.ego import commanded, ego_accel, ego_phase, gap_decision, outside, parked_ego
from jaxlc.sim.observation import (  # noqa: F401 (OBS_DIM, MIRROR_SIGNS, GAP_CLIP re-exported)
    GAP_CLIP,
    MIRROR_SIGNS,
    OBS_DIM,
    observation,
    observe_lanes,
    target_gaps_of,
)
from jaxlc.sim.road import (
    body_in_lane,
    ego_yaw_rate,
    lane_keeping_yaw_rate,
    lateral_offset,
    road_curvature,
)
from jaxlc.sim.state import (  # noqa: F401 (the state types and phases re-exported)
    ACT_DIM,
    ACTION_MIRROR,
    CRUISE,
    GAP,
    PHASES,
    RL,
    WAIT,
    Draws,
    Ego,
    EnvParams,
    EnvState,
    Traffic,
    TrafficDraws,
    action_dim,
    draw_episode,
    episode_params,
    episode_value,
)


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


def _advance(
    key: Array, state: EnvState, action: Array, p: EnvParams, spawn: bool
) -> tuple[EnvState, Array, dict[str, Array]]:
    """One dt of traffic and ego; returns ``(state, reward, info)`` (no observation); ``info``
    holds each of ``p.reward_terms`` under its name. The draws are ``p.draws``' (None: the
    traffic's own; a proposal's: ``jaxlc.validate``)."""
    p = episode_params(state, p)
    eg = state.ego
    u, ut = traffic_mod.step_draws(key, p, state)
    kappa = road_curvature(state, p)
    in_rl = eg.phase == RL
    held, held_long, lat, lon = executed_action(state, action, p)
    a_lat = p.max_yaw_acc * lat
    a_ego = ego_accel(state, p, lon)
    t = traffic_mod.step(state, u, ut, a_ego, a_lat, (eg.phase == WAIT) & spawn, p, kappa)
    traffic, spawned = t.traffic, t.spawned
    hazards = mobil.counts(t.lane_changes, t.around, eg, p) if p.mobil else {}
    ego = ego_phase(eg, t.motion, a_ego, held, held_long, spawned, t.before_inflow, u, p)
    if p.braking:
        hazards |= braking.counts(t.events, ego, p)
    if p.curvature_drawn:  # a new episode, a new road (the traffic keeps its s and lanes)
        kappa = jnp.where(
            spawned, episode_value(u.curvature, p.curvature_min, p.curvature_max, p), kappa
        )
    nb, leader_gap, leader_v = observe_lanes(traffic, ego, p, kappa)
    crashed = collided(traffic, ego, spawned, p, kappa)

    offset = lateral_offset(ego, p)
    # Comfort and success read the yaw rate relative to the lane's (= omega when straight).
    yaw_rate = ego_yaw_rate(ego, kappa, p)
    gaps = target_gaps_of(nb, ego, kappa, p)
    overlap = body_in_lane(ego, ego.target, p)  # () counted by r_gap in the RL phase only
    x = reward.Inputs(yaw_rate, a_lat, offset, crashed, ego, nb, eg, gaps, overlap)
    terms = {n: jnp.where(in_rl, v, 0.0) for n, v in reward.terms(x, p).items()}
    r = reward.total(terms)
    rl_reason = reward.end_reason(offset, ego.psi, yaw_rate, ego.steps, crashed, p, ego.v)
    accept, no_gap = gap_decision(ego, nb, p, kappa)
    reason = reward.episode_reason(in_rl, rl_reason, crashed, no_gap)
    if p.operating_speed:  # static: a command, or a gap found, outside the range is declined
        declined = (commanded(ego) | accept) & ~crashed & outside(ego.v, p.operating_speed)
        accept = accept & ~declined
        reason = jnp.where(declined, reward.DECLINED, reason).astype(jnp.int32)
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
    episode = state.episode  # an episode that ends draws the next one's (its ego not yet spawned)
    if p.drawn:
        episode = tuple(
            jnp.where(ended, n, o) for n, o in zip(draw_episode(key, p), episode, strict=True)
        )
    state = EnvState(
        traffic, ego, nb, leader_gap, leader_v, state.time + 1, road, state.drawn, episode
    )
    info = {
        "rl_step": in_rl,
        "phase": ego.phase,
        "reason": reason,
        "lane_change": accept,
        # () the yaw acceleration's action; (2,) with the longitudinal one ("policy")
        "action": held if held_long is None else jnp.stack([held, held_long]),
        **terms,  # each reward term by name (params.reward_terms)
        "episode_return": ep_return,
        "episode_steps": ego.steps,
        "offset": offset,
        **hazards,  # with env.mobil / env.braking: the traffic's events of this step
    }
    return state, r, info


def _warm_traffic(key: Array, state: EnvState, p: EnvParams) -> EnvState:
    """One warm-up step of the traffic alone: ``_advance``'s traffic, with its draws, while no
    ego is on the road and none spawns; the ego is not moved."""
    p = episode_params(state, p)
    u, ut = traffic_mod.step_draws(key, p)
    zero, kappa = jnp.float32(0.0), road_curvature(state, p)
    t = traffic_mod.step(state, u, ut, zero, zero, jnp.bool_(False), p, kappa)
    return state.replace(traffic=t.traffic, time=state.time + 1)


class LaneChangeEnv:
    """Functional env; every method is pure and jittable, and vmaps over key/state/action."""

    name = "LaneChange-v0"

    def default_params(self) -> EnvParams:
        return EnvParams()

    def observation_space(self, params: EnvParams) -> Box:
        return Box(-jnp.inf, jnp.inf, (OBS_DIM,))

    def action_space(self, params: EnvParams) -> Box:
        return Box(-1.0, 1.0, (action_dim(params),))

    def reset(
        self, key: Array, params: EnvParams, traffic_only: bool = False
    ) -> tuple[Array, EnvState]:
        """``(obs, state)``: an empty road, then ``warmup_steps`` of traffic (the ego spawns on
        a later step); ``obs`` is ``(OBS_DIM,)``, ``key`` a PRNG key. ``traffic_only``
        (static): the warm-up steps the traffic alone (``_warm_traffic``), a fraction of the cost;
        the ego, off the road all along, keeps its reset values where the full step lets it
        coast (nothing after its spawn reads them). Its traffic is the full step's to float32
        rounding, not to the bit: XLA's CPU code rounds an entry's headway one ulp apart in
        a few lanes in 10^4. The warm-up draws the traffic's own, whatever ``params.draws``."""
        p, lanes = params.replace(draws=None), params.lanes
        k_init, k_warm = jax.random.split(key)
        episode = draw_episode(k_init, p) if p.drawn else None  # the first episode's
        p = episode_params(EnvState(*(None,) * 8, episode), p)
        u = jax.random.uniform(k_init, (4, lanes))
        traffic = traffic_mod.empty(u, p)
        ego = parked_ego(p)
        road = None
        if p.curvature_drawn:  # its own key: a constant road's draws are left as they were
            u_road = jax.random.uniform(jax.random.fold_in(k_init, 1))
            road = episode_value(u_road, p.curvature_min, p.curvature_max, p)
        nb, leader_gap, leader_v = observe_lanes(
            traffic, ego, p, p.curvature if road is None else road
        )
        state = EnvState(
            traffic, ego, nb, leader_gap, leader_v, jnp.int32(0), road, episode=episode
        )

        def warm(s: EnvState, k: Array) -> tuple[EnvState, None]:
            if traffic_only:
                return _warm_traffic(k, s, p), None
            return _advance(k, s, jnp.zeros(action_dim(p)), p, spawn=False)[0], None

        state, _ = jax.lax.scan(warm, state, jax.random.split(k_warm, p.warmup_steps))
        if traffic_only:
            nb, leader_gap, leader_v = observe_lanes(
                state.traffic, state.ego, p, road_curvature(state, p)
            )
            state = state.replace(nb=nb, leader_gap=leader_gap, leader_v=leader_v)
        return observation(state, p), state.replace(time=jnp.int32(0))

    def step(
        self, key: Array, state: EnvState, action: Array, params: EnvParams
    ) -> tuple[Array, EnvState, Array, Array, Array, dict[str, Array]]:
        """Advance one dt with ``action`` ``(action_dim,)`` in [-1, 1] (read every ``k``-th RL
        step, ignored outside the RL phase). Returns ``(obs (OBS_DIM,), state, reward (),
        terminated (), truncated (), info)``: ``terminated``/``truncated`` refer to the RL
        manoeuvre (a timeout truncates unless ``params.terminal_timeout``); ``info`` has the
        reward terms, phase and ``reason`` codes of ``jaxlc.sim.reward.REASONS``."""
        episode = state.episode
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
        # Read with this step's episode values: on the step an episode ends, the terminal
        # observation is that episode's, not with the next one's draw.
        obs = observation(state.replace(episode=episode), params)
        return obs, state, r, terminated, truncated, info


def make(config: Config | EnvConfig | None = None, k: int = 1) -> tuple[LaneChangeEnv, EnvParams]:
    """``env, params = jaxlc.make()``.

    Args:
        config: a ``Config`` (its ``[env]`` and ``ddpg.gamma``) or an ``EnvConfig``; default
            ``configs/default.toml``.
        k: the action-update step (an action is held for ``k`` RL steps).

    Returns:
        The functional env and its ``EnvParams``.
    """
    if config is None:
        from jaxlc import config as config_mod

        config = config_mod.load()
    if isinstance(config, Config):
        return LaneChangeEnv(), EnvParams.from_config(config.env, config.ddpg.gamma, k)
    return LaneChangeEnv(), EnvParams.from_config(config, k=k)
