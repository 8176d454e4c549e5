"""The traffic's draws around the ego from a proposal, weighed against each of its components.

A ``Proposal`` is a mixture of traced ``Tilt``s (each leaf ``(K, ...)``), the traffic's own
distribution its defensive component; one draws a chunk (``drawn``, -1: the traffic's own). It
reaches the simulator as the source of the traffic's draws (``EnvParams.draws``), so
``env.step`` keeps ``(key, state, action, params)``. From the window's first ego phase
(``WINDOWS``: the gap's acceptance, or the ego's entry, which also changes which cases become
lane changes: ``rare.is_ratio_estimate``) a tilt draws the lag's yielding with probability
``yields`` and the braking events (``env.braking``) of ``ROLES`` (the target lane's lead and
lag, the own lane's leader, the others up to ``AHEAD`` ahead) at ``brake[role]`` per step,
their deceleration and duration from truncated exponentials; or, where ``conditional``, the
traffic's own braking given the role's first event within ``horizon`` trials
(``first_event_hazard``). ``TiltedEnv.step`` returns the step's ``Record`` in ``info["tilt"]``
(packed): the log ratio ``log p / q_k`` of the draws it used to every component, and the
statistics the fits read; the state keeps their sum (``EnvState.drawn``).
"""

from __future__ import annotations

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.evaluation import rare
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import GAP, RL, Draws, EnvParams, EnvState, LaneChangeEnv, TrafficDraws
from jaxlc.sim.leaders import ego_neighbour_roles
from jaxlc.sim.state import CRUISE, between

ROLES = ("lead", "lag", "own_leader", "ahead")
WINDOWS = {"acceptance": RL, "entry": CRUISE}  # the first ego phase whose braking is tilted
AHEAD = 100.0  # m: the "ahead" role, every other vehicle up to this far ahead of the ego


@flax.struct.dataclass
class Tilt:
    """One component's change of the traffic's draws (traced: a fit changes it without
    compiling again); in a ``Proposal`` each leaf has a leading ``(K,)`` axis."""

    brake: Array  # (4,) per-step probability a braking event starts, by ROLES
    brake_acc: Array  # () theta of the deceleration's uniform (> 0: harder)
    brake_time: Array  # () theta of the duration's uniform (> 0: longer)
    yields: Array  # () probability the lag yields
    # (4,) by ROLES: braking trials within which the role's conditional tilt puts its first
    # event (0: none), and 1 where the role's braking is drawn from that tilt, not ``brake``
    horizon: Array
    conditional: Array


@flax.struct.dataclass
class Record:
    """What the draws of a step (or, summed, a lane change) tell the weights and the fits."""

    log_r: Array  # (..., K) log p / q_k of the draws used, each component k
    trials: Array  # (..., 4) braking trials by ROLES (a vehicle that could start an event)
    events: Array  # (..., 4) braking events started by ROLES
    first: Array  # (..., 4) braking trials up to the role's first event (all without one)
    acc_sum: Array  # (...) the started events' deceleration uniforms, summed
    time_sum: Array  # (...) their duration uniforms
    yield_trials: Array  # (...) 1 on the step of acceptance
    yield_events: Array  # (...) 1 where the lag yielded then

    def pack(self) -> Array:
        """``(..., K + 16)`` float32: the engine's ``tilt`` measure."""
        parts = [self.log_r, self.trials, self.events, self.first]
        parts += [x[..., None] for x in (self.acc_sum, self.time_sum)]
        parts += [x[..., None] for x in (self.yield_trials, self.yield_events)]
        return jnp.concatenate([jnp.asarray(x, jnp.float32) for x in parts], axis=-1)

    @classmethod
    def unpack(cls, v) -> Record:
        """``pack``'s inverse, of numpy or JAX arrays ``(..., K + 16)``."""
        k, r = v.shape[-1] - 16, len(ROLES)
        cut = [v[..., i : i + r] for i in (k, k + r, k + 2 * r)]
        return cls(v[..., :k], *cut, *(v[..., k + 3 * r + i] for i in range(4)))


@flax.struct.dataclass
class Proposal:
    """A mixture of ``Tilt``s (leaves ``(K, ...)``); ``drawn`` () int32 the component that
    draws (-1: the traffic's own), ``first`` () int32 the window's first phase (``WINDOWS``)."""

    tilts: Tilt
    drawn: Array
    first: Array

    @property
    def size(self) -> int:
        """Components ``K``."""
        return self.tilts.yields.shape[0]

    def draw(self, key: Array, state: EnvState, p: EnvParams) -> tuple[Draws, TrafficDraws]:
        """The step's draws (``jaxlc.sim.traffic.step_draws``): the drawing component's."""
        return _draws(self, key, state, p)[:2]


def nominal(p: EnvParams) -> Tilt:
    """The traffic's own distribution as a tilt: every weight exactly 1."""
    zeros = jnp.zeros(len(ROLES), jnp.float32)
    brake = jnp.full(len(ROLES), start_probability(p), jnp.float32)
    return Tilt(brake, jnp.float32(0.0), jnp.float32(0.0), jnp.float32(p.p_yield), zeros, zeros)


def stack(tilts: list[Tilt]) -> Tilt:
    """The components ``(K, ...)`` of a mixture."""
    return jax.tree.map(lambda *a: jnp.stack([jnp.asarray(x, jnp.float32) for x in a]), *tilts)


def first_event_hazard(p_fire: Array, horizon: Array, trials: Array, events: Array) -> Array:
    """``(4,)`` per-trial probability of a braking event under each role's conditional tilt,
    given its ``trials`` and ``events`` so far ``(4,)``: the traffic's event conditioned on the
    first falling within ``horizon`` trials, ``p / (1 - (1 - p)^(horizon - trials))`` before
    it (1 on the last), ``p_fire`` once the role braked, past its horizon, or without one.
    A path whose first event comes at trial ``c <= horizon`` has the ratio
    ``q / p = 1 / (1 - (1 - p)^horizon)`` whatever ``c``."""
    left = horizon - trials
    before = (events < 0.5) & (left >= 1.0)
    q = p_fire / -jnp.expm1(jnp.maximum(left, 1.0) * jnp.log1p(-p_fire))
    return jnp.where(before, jnp.minimum(q, 1.0), p_fire)


def roles(state: EnvState, p: EnvParams) -> Array:
    """``(4, rows, slots)`` bool: ``leaders.ego_neighbour_roles`` (the target lane's lead and
    lag, the own lane's leader) and the others up to ``AHEAD`` ahead."""
    tr, eg = state.traffic, state.ego
    near = ego_neighbour_roles(tr, eg, p)
    others = tr.active & (tr.x > eg.x) & (tr.x < eg.x + AHEAD) & ~jnp.any(near, axis=0)
    return jnp.concatenate([near, others[None]])


def _fire(t: Tilt, role: Array, so_far: Record, p_fire: Array) -> Array:
    """``(rows, slots)``: each vehicle's per-step probability of a braking event under ``t``
    (the traffic's away from the ego; a conditional role's given its events so far)."""
    # A rate within 1 ppm of the traffic's is the traffic's (eager and compiled expm1 differ
    # in the last bit): its weight is exactly 1.
    q_role = jnp.where(jnp.abs(t.brake - p_fire) <= 1e-6 * p_fire, p_fire, t.brake)
    q_cond = first_event_hazard(p_fire, t.horizon, so_far.trials, so_far.events)
    q_role = jnp.where(t.conditional > 0.5, q_cond, q_role)
    q_fire = jnp.max(jnp.where(role, q_role[:, None, None], 0.0), axis=0)
    return jnp.where(jnp.any(role, axis=0), jnp.maximum(q_fire, 1e-12), p_fire)


def _draws(q: Proposal, key: Array, state: EnvState, p: EnvParams) -> tuple:
    """``(u, ut, role)``: the step's draws from component ``q.drawn`` (the traffic's own at
    -1) and the roles ``(4, rows, slots)`` of the vehicles whose braking it tilts."""
    so_far = Record.unpack(state.drawn)
    t = jax.tree.map(lambda a: a[jnp.maximum(q.drawn, 0)], q.tilts)
    own = q.drawn < 0  # the draws are the traffic's; the ratios still against each component
    u = Draws.draw(key, p.lanes)
    gap = state.ego.phase == GAP
    p_yield = jnp.float32(p.p_yield)
    q_yield = jnp.where(own, p_yield, t.yields)
    u = u._replace(yields=jnp.where(gap, rare.tilt_bernoulli(u.yields, p_yield, q_yield), u.yields))
    if not p.braking:  # static
        ut = TrafficDraws.draw(key, p.lanes, p.slots_per_lane) if p.mobil else None
        return u, ut, None
    ut = TrafficDraws.draw(key, p.lanes, p.slots_per_lane)
    role = roles(state, p) & (state.ego.phase >= q.first)  # (roles, rows, slots)
    near, p_fire = jnp.any(role, axis=0), start_probability(p)
    q_fire = _fire(t, role, so_far, p_fire)
    acc, time = (jnp.where(own, 0.0, th) for th in (t.brake_acc, t.brake_time))
    ut = ut._replace(
        brake_fire=rare.tilt_bernoulli(ut.brake_fire, p_fire, jnp.where(own, p_fire, q_fire)),
        brake_acc=jnp.where(near, rare.tilt_exponential(ut.brake_acc, acc), ut.brake_acc),
        brake_time=jnp.where(near, rare.tilt_exponential(ut.brake_time, time), ut.brake_time),
    )
    return u, ut, role


class TiltedEnv(LaneChangeEnv):
    """``LaneChangeEnv`` under ``params.draws``, a ``Proposal``: its reset starts the state's
    ``Record`` at 0, its step adds the step's (``info["tilt"]``, packed)."""

    def reset(self, key: Array, params: EnvParams, traffic_only: bool = False) -> tuple:
        obs, state = super().reset(key, params, traffic_only)
        width = params.draws.size + 3 * len(ROLES) + 4
        return obs, state.replace(drawn=jnp.zeros(width, jnp.float32))

    def step(self, key: Array, state: EnvState, action: Array, params: EnvParams) -> tuple:
        p, q = params, params.draws
        u, ut, role = _draws(q, key, state, p)  # the draws the simulator makes (the same ops)
        obs, new, r, term, trunc, info = super().step(key, state, action, p)
        accept = (state.ego.phase == GAP) & info["lane_change"]
        so_far, zero, zeros = Record.unpack(state.drawn), jnp.float32(0.0), jnp.zeros(len(ROLES))
        p_yield = jnp.float32(p.p_yield)
        yielding = jax.vmap(lambda t: rare.bernoulli_log_ratio(u.yields, p_yield, t.yields))
        log_r = jnp.where(accept, yielding(q.tilts), 0.0)  # (K,)
        trials = events = first = zeros
        sums = (zero, zero)
        if p.braking:
            p_fire, near = start_probability(p), jnp.any(role, axis=0)
            fired = ut.brake_fire < p_fire
            length = between(ut.brake_time, p.braking_time_min, p.braking_time_max)
            tr = new.traffic
            started = fired & tr.active & (tr.brake_left == length)
            eligible = started | (~fired & tr.active & (tr.brake_left <= 0.0))

            def braking_log_ratio(t: Tilt) -> Array:
                q_fire = _fire(t, role, so_far, p_fire)
                fire = rare.bernoulli_log_ratio(ut.brake_fire, p_fire, q_fire)
                cont = rare.exponential_log_ratio(ut.brake_acc, t.brake_acc)
                cont += rare.exponential_log_ratio(ut.brake_time, t.brake_time)
                return jnp.sum(jnp.where(near & eligible, fire, 0.0)), jnp.sum(
                    jnp.where(near & started, cont, 0.0)
                )

            fire, cont = jax.vmap(braking_log_ratio)(q.tilts)
            log_r = log_r + fire
            log_r += cont
            trials = jnp.sum(role & eligible, axis=(1, 2))
            events = jnp.sum(role & started, axis=(1, 2))
            sums = tuple(
                jnp.sum(jnp.where(near & started, x, 0.0)) for x in (ut.brake_acc, ut.brake_time)
            )
            first = jnp.where(so_far.events < 0.5, trials, 0.0)
        yielded = (u.yields < p.p_yield).astype(jnp.float32)
        rec = Record(log_r, trials, events, first, *sums, accept, accept * yielded).pack()
        return obs, new.replace(drawn=state.drawn + rec), r, term, trunc, {**info, "tilt": rec}
