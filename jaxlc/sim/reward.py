"""Reward, eqs. (8)-(11) of the paper, and the episode's termination rules.

    r_s = -w1*|omega| - w2*|a_lat|                        (8)  smoothness
    r_e = -w3*dt                                          (9)  elapsed time
    r_d = -w4*|dd|                   if |dd| <= D          (10)
          -w4*|dd| * 10/(1-gamma)    if |dd| >  D          (11)
    r   = r_s + r_e + r_d

omega (rad/s) and the lateral offset dd (m) are those after the step, a_lat (rad/s^2) the
executed yaw acceleration. A collision ends the episode with the out-of-bounds penalty at
|dd| = max(|dd|, D).

The reward is the sum of its terms, each a ``Term`` (name, the config keys that weight it, a
function of the step's ``Inputs``): the paper's three are ``PAPER``; ``MANOEUVRE`` holds four
more for the whole manoeuvre (longitudinal comfort, lateral comfort past ISO 11270's bounds,
headway to the target lane's vehicles, speed), off unless named. The config's
``env.reward_terms`` names the terms a run uses; a term of your own is ``register``-ed under a
new name and named there. Every output that shows the reward term by term (the env's
``info``, training metrics, evaluation tables, the gym and gymnax infos, TensorBoard) iterates
over ``params.reward_terms``, so a registered term appears in each of them.

    def lane_centre(x: reward.Inputs, p) -> jax.Array:
        return -0.1 * jnp.abs(x.offset)

    reward.register(reward.Term("r_centre", (), lane_centre))
    cfg = config.load(overrides=['env.reward_terms=["r_s", "r_e", "r_d", "r_centre"]'])
"""

from __future__ import annotations

import functools
import operator
from collections.abc import Callable, Iterable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax import Array


class Inputs(NamedTuple):
    """What a reward term reads after one RL step (each ``()``)."""

    yaw_rate: Array  # rad/s, relative to the lane's (omega on a straight road)
    a_lat: Array  # rad/s^2, the yaw acceleration executed this step
    offset: Array  # m, signed offset from the target lane's centre line
    collided: Array  # bool
    ego: Any = None  # jaxlc.sim.state.Ego after the step (speed, acceleration, heading)
    nb: Any = None  # jaxlc.sim.gap.Neighbours: the target lane's vehicles after the step
    before: Any = None  # the Ego before the step (jerks are differences over dt)
    gaps: Any = None  # (lead_gap, lag_gap), m along the target lane (observation.target_gaps)
    overlap: Any = None  # bool, the ego's body overlaps the target lane after the step


class Term(NamedTuple):
    """One reward term; ``fn(inputs, params)`` is its value for one RL step before
    ``reward_scale``, ``weights`` the ``[env]`` keys it reads (documentation and tests)."""

    name: str  # its key in info, metrics, evaluation tables and TensorBoard
    weights: tuple[str, ...]
    fn: Callable[[Inputs, Any], Array]


def smoothness(x: Inputs, p) -> Array:
    """Eq. (8)."""
    return -p.w1 * jnp.abs(x.yaw_rate) - p.w2 * jnp.abs(x.a_lat)


def elapsed(x: Inputs, p) -> Array:
    """Eq. (9)."""
    return -p.w3 * p.dt * jnp.ones_like(x.yaw_rate)


def deviation(x: Inputs, p) -> Array:
    """Eqs. (10)-(11); a collision costs the out-of-bounds penalty at max(|dd|, D)."""
    dev = jnp.abs(x.offset)
    beyond = -p.w4 * jnp.maximum(dev, p.border) * 10.0 / (1.0 - p.gamma)
    return jnp.where(x.collided | (dev > p.border), beyond, -p.w4 * dev)


PAPER: tuple[Term, ...] = (
    Term("r_s", ("w1", "w2"), smoothness),
    Term("r_e", ("w3",), elapsed),
    Term("r_d", ("w4", "border"), deviation),
)


def longitudinal_comfort(x: Inputs, p) -> Array:
    """``-w_long_acc*|a_x| - w_long_jerk*|a_x - a_x,before|/dt``: the ego's longitudinal
    acceleration after the step and its change over the step."""
    jerk = (x.ego.accel - x.before.accel) / p.dt
    return -p.w_long_acc * jnp.abs(x.ego.accel) - p.w_long_jerk * jnp.abs(jerk)


def lateral_comfort(x: Inputs, p) -> Array:
    """ISO 11270's two bounds as costs of their excess: ``-w_lat_acc*max(|a_y| - lat_acc_max,
    0) - w_lat_jerk*max(|j_y| - lat_jerk_max, 0)``, a_y = v*omega after the step, j_y its change
    over the step / dt (the evaluation's jerk averages over 0.5 s: ``evaluation.safety``)."""
    a_y, a_y0 = x.ego.v * x.ego.omega, x.before.v * x.before.omega
    over_a = jnp.maximum(jnp.abs(a_y) - p.lat_acc_max, 0.0)
    over_j = jnp.maximum(jnp.abs(a_y - a_y0) / p.dt - p.lat_jerk_max, 0.0)
    return -p.w_lat_acc * over_a - p.w_lat_jerk * over_j


def headway_shortfall(x: Inputs, p) -> Array:
    """``-w_headway * (max(headway_min - h_lead, 0) + max(headway_min - h_lag, 0))`` while the
    ego's body overlaps the target lane (the evaluation counts from the first overlap on,
    ``evaluation.safety.counted``): h_lead = lead gap / ego speed, h_lag = lag gap / lag speed;
    none for a missing vehicle or a standing follower."""
    lead_gap, lag_gap = x.gaps

    def short(gap: Array, v: Array, present: Array) -> Array:
        h = jnp.where(v > 0.0, gap / jnp.where(v > 0.0, v, 1.0), jnp.inf)
        return jnp.where(present, jnp.maximum(p.headway_min - h, 0.0), 0.0)

    total = short(lead_gap, x.ego.v, x.nb.has_a1) + short(lag_gap, x.nb.b1_v, x.nb.has_b1)
    return -p.w_headway * jnp.where(x.overlap, total, 0.0)


def speed_keeping(x: Inputs, p) -> Array:
    """``-w_speed * |v - v0| / v0``: the ego's speed against its desired speed."""
    return -p.w_speed * jnp.abs(x.ego.v - x.ego.v0) / x.ego.v0


# The whole manoeuvre's terms ([D], off by default: not in env.reward_terms, weights 0).
MANOEUVRE: tuple[Term, ...] = (
    Term("r_long", ("w_long_acc", "w_long_jerk"), longitudinal_comfort),
    Term("r_lat", ("w_lat_acc", "w_lat_jerk", "lat_acc_max", "lat_jerk_max"), lateral_comfort),
    Term("r_gap", ("w_headway", "headway_min"), headway_shortfall),
    Term("r_speed", ("w_speed",), speed_keeping),
)
# Terms by name: the paper's, and those registered. Filled at import (the paper's) and by
# ``register`` before a run is configured, as gymnasium registers its envs.
_REGISTRY: dict[str, Term] = {t.name: t for t in (*PAPER, *MANOEUVRE)}


def register(term: Term) -> Term:
    """Make ``term`` nameable in ``env.reward_terms``; a name already taken by another
    function is refused (``ValueError``). Returns the term."""
    known = _REGISTRY.get(term.name)
    if known is not None and known != term:
        raise ValueError(f"reward term {term.name!r} is registered already: choose another name")
    if term.name in ("reward", "ret", "steps", "reason", "at_step"):
        raise ValueError(f"reward term name {term.name!r} is taken by a metric")
    _REGISTRY[term.name] = term
    return term


def lookup(names: Iterable[str]) -> tuple[Term, ...]:
    """The terms named (``KeyError`` naming the unknown and the known ones)."""
    names = tuple(names)
    unknown = [n for n in names if n not in _REGISTRY]
    if unknown:
        raise KeyError(
            f"unknown reward term(s) {unknown}: known are {sorted(_REGISTRY)} "
            "(a term of your own: jaxlc.sim.reward.register)"
        )
    return tuple(_REGISTRY[n] for n in names)


def names(p) -> tuple[str, ...]:
    """The names of ``p``'s reward terms, in their order."""
    return tuple(t.name for t in p.reward_terms)


def terms(x: Inputs, p) -> dict[str, Array]:
    """``{name: value}`` of ``p.reward_terms`` for one RL step, each times ``reward_scale``."""
    return {t.name: p.reward_scale * t.fn(x, p) for t in p.reward_terms}


def total(values: dict[str, Array]) -> Array:
    """The reward: the terms' sum, left to right (no 0.0 added: -0.0 stays -0.0)."""
    return functools.reduce(operator.add, values.values())


# Why an episode ended (info["reason"]).
# DECLINED: a lane change commanded, or its gap found, outside the operating range
# (env.operating_speed) is not taken; the episode ends there, apart from the failures (none
# in its absence).
NONE, SUCCESS, OUT_OF_BOUNDS, COLLISION, TIMEOUT, NO_GAP, DECLINED = 0, 1, 2, 3, 4, 5, 6
REASONS = ("none", "success", "out_of_bounds", "collision", "timeout", "no_gap", "declined")


def step_limit(p) -> Array:
    """``()`` RL steps a manoeuvre may take before it times out, ``round(manoeuvre_time_limit
    / dt)`` (counting steps, not summing dt, keeps the limit exact in float32); a Python
    ``int`` unless either is traced, so a program's static step cap reads it under ``jit``.
    With ``manoeuvre_distance`` on, the longest, ``manoeuvre_time_max``'s (``steps_allowed``
    is a manoeuvre's own)."""
    t = p.manoeuvre_time_max if p.manoeuvre_distance else p.manoeuvre_time_limit
    dt = p.dt
    if isinstance(t, jax.core.Tracer) or isinstance(dt, jax.core.Tracer):
        return jnp.round(t / dt)
    return round(float(t) / float(dt))


def steps_allowed(v: Array | None, p) -> Array:
    """``()`` RL steps a manoeuvre at speed ``v`` (m/s, now) may take: ``step_limit``; with
    ``manoeuvre_distance`` D on, ``round(clip(D / v, manoeuvre_time_limit,
    manoeuvre_time_max) / dt)``: as long as the distance takes at that speed, within the two."""
    if not p.manoeuvre_distance:  # static: today's program
        return step_limit(p)
    if v is None:
        raise ValueError("env.manoeuvre_distance is on: the timeout needs the ego's speed")
    slowest = p.manoeuvre_distance / p.manoeuvre_time_max  # at or below it: the longest limit
    t = p.manoeuvre_distance / jnp.maximum(v, slowest)
    return jnp.round(jnp.clip(t, p.manoeuvre_time_limit, p.manoeuvre_time_max) / p.dt)


def end_reason(
    offset: Array,
    psi: Array,
    omega: Array,
    manoeuvre_steps: Array,
    collided: Array,
    p,
    v: Array | None = None,
) -> Array:
    """``()`` int32 reason code of the manoeuvre after an RL step: the first that holds of
    collision, out of bounds, success, timeout (NONE while it goes on; ``v``, the ego's speed,
    sets the limit where ``manoeuvre_distance`` is on); the episode's own, any phase, is
    ``episode_reason``'s."""
    out = jnp.abs(offset) > p.border
    success = (
        (jnp.abs(offset) <= p.success_offset)
        & (jnp.abs(psi) <= p.success_heading)
        & (jnp.abs(omega) <= p.success_yaw_rate)
    )
    timeout = manoeuvre_steps >= steps_allowed(v, p)
    return jnp.select(
        [collided, out, success, timeout],
        [COLLISION, OUT_OF_BOUNDS, SUCCESS, TIMEOUT],
        NONE,
    ).astype(jnp.int32)


def episode_reason(in_rl: Array, rl_reason: Array, crashed: Array, no_gap: Array) -> Array:
    """``()`` int32 reason code of ``REASONS``: the RL manoeuvre's own, else a collision or
    no gap before it, else NONE."""
    before_rl = jnp.where(crashed, COLLISION, jnp.where(no_gap, NO_GAP, NONE))
    return jnp.where(in_rl, rl_reason, before_rl).astype(jnp.int32)
