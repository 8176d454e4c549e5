"""The traffic's random draws around the ego from a tilted proposal, each lane change weighted
by its likelihood ratio (importance sampling: ``jaxlc.evaluation.rare``).

A ``Proposal`` tilts, from the step the ego accepts its gap on (so the number of lane changes,
decided before, keeps the traffic's own distribution, and an estimate per lane change needs
no ratio of two estimates; ``tilt_from`` may start the braking's tilt earlier, ``TILT_FROM``):

- whether the target lane's lag yields (``p_yield``): drawn with probability ``yields``;
- braking events (``env.braking``) of the vehicles around the ego in the RL phase (the
  target lane's lead and lag, the own lane's leader, and every other vehicle up to ``AHEAD``
  ahead of it in any lane, found on the state before the step):
  an event starts with probability ``brake[role]`` per step instead of ``1 - exp(-rate dt)``,
  its deceleration and duration from truncated exponentials of ``brake_acc`` and
  ``brake_time``; or, for a role whose ``conditional`` is set, from the traffic's own draws
  conditioned on the role's first event falling within its first ``horizon`` braking trials
  (``first_event_hazard``), every event after it the traffic's own.

Every other draw is the traffic's own. With ``drawn_nominal`` set, the draws are all the
traffic's own and their log ratio is still taken against the proposal: the nominal share of a
defensive mixture (``jaxlc.evaluation.validation``). ``TiltedEnv.step`` hands the tilted
draws to the simulator (``LaneChangeEnv.step(..., draws=)``) and returns in ``info`` the log
ratio of the draws the step used (``log_w``: a braking draw counts for a vehicle that could
start an event, the yielding draw on the step of acceptance) and the CE's statistics
(``tilt``, ``STATS``). Its ``so_far`` is the statistics of the steps before (the rollout's
sum of ``tilt``), which the conditional hazard reads: the role's trials so far and whether it
braked yet. The statistics hold, for every role with a ``horizon``, the log ratio of the role's
braking draws to its conditional tilt (``cond_``), so a mixture of one-role tilts
(``jaxlc.evaluation.mixture``) weighs each lane change against every component.
``nominal(params)`` draws exactly what the simulator draws, with weights of exactly 1.
"""

from __future__ import annotations

import flax.struct
import jax.numpy as jnp
import numpy as np
from jax import Array

from jaxlc.evaluation import rare
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import GAP, RL, Draws, EnvParams, EnvState, LaneChangeEnv, TrafficDraws
from jaxlc.sim.leaders import ego_neighbour_roles
from jaxlc.sim.state import CRUISE, between

ROLES = ("lead", "lag", "own_leader", "ahead")
# Where the braking's tilt starts (``Proposal.tilt_from`` indexes it): the gap's acceptance,
# the command (the gap search too), or the ego's first step (its cruise too). From the command
# or the entry the proposal also changes which cases become lane changes
# (``rare.is_ratio_estimate``); a braking event around the ego before its command is tilted
# only from the entry.
TILT_FROM = ("acceptance", "command", "entry")
_FIRST_PHASE = (RL, GAP, CRUISE)  # by TILT_FROM: the first phase whose braking is tilted
AHEAD = 100.0  # m: the "ahead" role, every other vehicle up to this far ahead of the ego
# The statistics a step adds up for the CE (``info["tilt"]``), in this order.
STATS = (
    *(f"brake_trials_{r}" for r in ROLES),
    *(f"brake_events_{r}" for r in ROLES),
    "brake_acc_sum",
    "brake_time_sum",
    "yield_trials",
    "yield_events",
    # braking trials up to the role's first event (all of them without one)
    *(f"brake_first_{r}" for r in ROLES),
    # log p / q of the role's braking draws under its conditional tilt (0 without a horizon)
    *(f"cond_{r}" for r in ROLES),
)
# (4,) by ROLES: the columns of each role's braking trials, events and conditional log ratio
# in ``STATS`` (numpy: no device array at import)
TRIALS, EVENTS, COND = (
    np.asarray([STATS.index(f"{s}_{r}") for r in ROLES])
    for s in ("brake_trials", "brake_events", "cond")
)


@flax.struct.dataclass
class Proposal:
    """A proposal's parameters (traced: the CE changes them without compiling again)."""

    brake: Array  # (4,) per-step probability a braking event starts, by ROLES
    brake_acc: Array  # () theta of the deceleration's uniform (> 0: harder)
    brake_time: Array  # () theta of the duration's uniform (> 0: longer)
    yields: Array  # () probability the lag yields
    tilt_from: Array | float = 0.0  # () index into TILT_FROM
    drawn_nominal: Array | float = 0.0  # () 1: draw the traffic's own, weigh against this
    # (4,) by ROLES: braking trials within which the role's conditional tilt puts its first
    # event (0: none), and 1 where the role's braking is drawn from that tilt, not ``brake``
    horizon: Array | float = 0.0
    conditional: Array | float = 0.0

    def to_dict(self) -> dict[str, object]:
        return {k: jnp.asarray(v).tolist() for k, v in vars(self).items()}


def nominal(p: EnvParams) -> Proposal:
    """The traffic's own distribution: every weight exactly 1."""
    return Proposal(
        brake=jnp.full(len(ROLES), start_probability(p), jnp.float32),
        brake_acc=jnp.float32(0.0),
        brake_time=jnp.float32(0.0),
        yields=jnp.float32(p.p_yield),
        tilt_from=jnp.float32(0.0),
        drawn_nominal=jnp.float32(0.0),
        horizon=jnp.zeros(len(ROLES), jnp.float32),
        conditional=jnp.zeros(len(ROLES), jnp.float32),
    )


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


def from_dict(d: dict) -> Proposal:
    """A proposal as ``to_dict`` wrote it (``from_command``, 0 or 1, is ``tilt_from``'s older
    name)."""
    d = {("tilt_from" if k == "from_command" else k): v for k, v in d.items()}
    return Proposal(**{k: jnp.asarray(v, jnp.float32) for k, v in d.items()})


def roles(state: EnvState, p: EnvParams) -> Array:
    """``(4, rows, slots)`` bool: ``leaders.ego_neighbour_roles`` (the target lane's lead and
    lag, the own lane's leader) and the others up to ``AHEAD`` ahead."""
    tr, eg = state.traffic, state.ego
    near = ego_neighbour_roles(tr, eg, p)
    others = tr.active & (tr.x > eg.x) & (tr.x < eg.x + AHEAD) & ~jnp.any(near, axis=0)
    return jnp.concatenate([near, others[None]])


class TiltedEnv(LaneChangeEnv):
    """``LaneChangeEnv`` whose step draws from ``proposal`` (traced arrays are fine: build it
    inside the jitted function) and reports ``log_w`` and ``tilt`` in ``info``."""

    stats = len(STATS)

    def __init__(self, proposal: Proposal):
        self.proposal = proposal

    def step(self, key, state, action, params, draws=(), so_far=None):
        p, q = params, self.proposal
        so_far = jnp.zeros(len(STATS)) if so_far is None else so_far  # (STATS,) steps before
        own = q.drawn_nominal > 0.5  # the draws are the traffic's; the ratios still against q
        u = Draws.draw(key, p.lanes)
        gap = state.ego.phase == GAP
        p_yield = jnp.float32(p.p_yield)
        q_yield = jnp.where(own, p_yield, q.yields)
        u = u._replace(
            yields=jnp.where(gap, rare.tilt_bernoulli(u.yields, p_yield, q_yield), u.yields)
        )
        ut = TrafficDraws.draw(key, p.lanes, p.slots_per_lane) if p.mobil or p.braking else None
        if p.braking:
            phase = state.ego.phase
            first = jnp.asarray(_FIRST_PHASE)[jnp.round(q.tilt_from).astype(jnp.int32)]
            tilted = phase >= first  # RL is the last phase: from acceptance, the RL phase
            role = roles(state, p) & tilted  # (roles, rows, slots)
            near = jnp.any(role, axis=0)
            p_fire = start_probability(p)
            # A rate within 1 ppm of the traffic's is the traffic's (eager and compiled
            # expm1 differ in the last bit): its weight is exactly 1.
            q_role = jnp.where(jnp.abs(q.brake - p_fire) <= 1e-6 * p_fire, p_fire, q.brake)
            horizon = jnp.broadcast_to(q.horizon, (len(ROLES),))
            q_cond = first_event_hazard(p_fire, horizon, so_far[TRIALS], so_far[EVENTS])
            q_role = jnp.where(jnp.broadcast_to(q.conditional, q_cond.shape) > 0.5, q_cond, q_role)
            q_fire = jnp.max(jnp.where(role, q_role[:, None, None], 0.0), axis=0)
            q_fire = jnp.where(near, jnp.maximum(q_fire, 1e-12), p_fire)
            acc, time = (jnp.where(own, 0.0, th) for th in (q.brake_acc, q.brake_time))
            ut = ut._replace(
                brake_fire=rare.tilt_bernoulli(
                    ut.brake_fire, p_fire, jnp.where(own, p_fire, q_fire)
                ),
                brake_acc=jnp.where(near, rare.tilt_exponential(ut.brake_acc, acc), ut.brake_acc),
                brake_time=jnp.where(
                    near, rare.tilt_exponential(ut.brake_time, time), ut.brake_time
                ),
            )
        obs, new, r, term, trunc, info = super().step(key, state, action, params, (u, ut))
        accept = gap & info["lane_change"]
        log_w = jnp.where(accept, rare.bernoulli_log_ratio(u.yields, p_yield, q.yields), 0.0)
        zeros = jnp.zeros(len(ROLES))
        stats = [zeros, zeros, jnp.zeros(2)]
        first = cond = zeros
        if p.braking:
            fired = ut.brake_fire < p_fire
            length = between(ut.brake_time, p.braking_time_min, p.braking_time_max)
            tr = new.traffic
            started = fired & tr.active & (tr.brake_left == length)
            eligible = started | (~fired & tr.active & (tr.brake_left <= 0.0))
            used = near & eligible
            log_w += jnp.sum(
                jnp.where(used, rare.bernoulli_log_ratio(ut.brake_fire, p_fire, q_fire), 0.0)
            )
            cont = rare.exponential_log_ratio(ut.brake_acc, q.brake_acc)
            cont += rare.exponential_log_ratio(ut.brake_time, q.brake_time)
            log_w += jnp.sum(jnp.where(near & started, cont, 0.0))
            trials = jnp.sum(role & eligible, axis=(1, 2))
            events = jnp.sum(role & started, axis=(1, 2))
            sums = jnp.stack(
                [jnp.sum(jnp.where(near & started, x, 0.0)) for x in (ut.brake_acc, ut.brake_time)]
            )
            stats = [trials, events, sums]
            first = jnp.where(so_far[EVENTS] < 0.5, trials, 0.0)
            # each role's draws against its own conditional tilt: (4, rows, slots) -> (4,)
            r_cond = rare.bernoulli_log_ratio(ut.brake_fire, p_fire, q_cond[:, None, None])
            cond = jnp.sum(jnp.where(role & eligible, r_cond, 0.0), axis=(1, 2))
        yielded = (u.yields < p.p_yield).astype(jnp.float32)
        stats.append(jnp.stack([accept, accept * yielded]).astype(jnp.float32))
        stats += [first, cond]
        tilt = jnp.concatenate([s.astype(jnp.float32) for s in stats])
        return obs, new, r, term, trunc, {**info, "log_w": log_w, "tilt": tilt}
