"""The simulator's types: its state (``Traffic``, ``Ego``, ``EnvState``), the ego's phases
and a step's random draws; its parameters, ``EnvParams``, are ``jaxlc.sim.params``'s."""

from __future__ import annotations

from typing import Any, NamedTuple

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.sim import gap
from jaxlc.sim.params import EnvParams  # noqa: F401 (the simulator's modules import it here)

WAIT, CRUISE, GAP, RL = 0, 1, 2, 3
PHASES = ("wait", "cruise", "gap", "rl")
ACT_DIM = 1  # the paper's action: the yaw acceleration alone (env.longitudinal = "idm")
# Each action entry's sign under the reflection y -> -y: the yaw acceleration flips, the
# longitudinal acceleration (env.longitudinal = "policy") does not.
ACTION_MIRROR = (-1.0, 1.0)


def action_dim(p: Any) -> int:
    """The action's length under ``p`` (an ``EnvParams`` or ``EnvConfig``): 1, the yaw
    acceleration; 2 with ``longitudinal = "policy"``, then the longitudinal one."""
    return 2 if p.longitudinal == "policy" else 1


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
    # With env.mobil (None, no leaf, otherwise: the paper's traffic, whose rows are lanes).
    # A slot's row is then the lane it entered; the lane it drives in is ``lane``.
    lane: Array | None = None  # (lanes, slots) int32 lane driven in (the target while changing)
    lane_from: Array | None = None  # (lanes, slots) int32 lane of the last lane change's start
    lc_time: Array | None = None  # (lanes, slots) s since the last lane change started
    lc_dur: Array | None = None  # (lanes, slots) s that lane change lasts
    # With env.braking (None otherwise): the braking event under way, if any.
    brake_left: Array | None = None  # (lanes, slots) s of braking left (0: none)
    brake_acc: Array | None = None  # (lanes, slots) its deceleration, m/s^2 (> 0)


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
    # () longitudinal action executed (held for k steps), in [-1, 1], with
    # longitudinal = "policy"; None (no leaf) otherwise, whose state is the paper's.
    held_long: Array | None = None


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
    # () a proposal's statistics of the draws so far (``params.draws``); None (no leaf) else
    drawn: Array | None = None
    # The episode's values of the keys drawn per episode (``params.drawn``, in its order);
    # None (no leaf) when every key is a constant.
    episode: tuple[Array, ...] | None = None


def draw_episode(key: Array, p: EnvParams) -> tuple[Array, ...]:
    """An episode's values of ``p.drawn``, each ``episode_value`` of ``p.ranges``, from
    ``fold_in(key, 2)`` (the step's other draws are left as they were)."""
    u = jax.random.uniform(jax.random.fold_in(key, 2), (len(p.drawn),))
    return tuple(episode_value(u[i], lo, hi, p) for i, (lo, hi) in enumerate(p.ranges))


def episode_params(state: EnvState, p: EnvParams) -> EnvParams:
    """``p`` with the episode's drawn values (``state.episode``) in place of the ranges' middles."""
    return (
        p if state.episode is None else p.replace(**dict(zip(p.drawn, state.episode, strict=True)))
    )


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


class TrafficDraws(NamedTuple):
    """The step's uniform numbers of the traffic's own decisions, ``(lanes, slots)`` each, one
    per vehicle slot: 64 bits drawn from ``fold_in(step key, 1)``, one counter-based hash of
    them per number (``_mix``), only with ``env.mobil`` or ``env.braking``, so with both off
    the traffic's draws are the paper's traffic's alone."""

    lc_fire: Array  # the driver weighs a lane change this step (< 1 - exp(-mobil_rate*dt))
    lc_time: Array  # the lane change's duration in [lane_change_time_min, _max)
    brake_fire: Array  # a braking event starts (< 1 - exp(-braking_rate*dt))
    brake_acc: Array  # its deceleration in [braking_decel_min, _max)
    brake_time: Array  # its duration in [braking_time_min, _max)

    @classmethod
    def draw(cls, key: Array, lanes: int, slots: int) -> TrafficDraws:
        # 64 bits of threefry from the step's key, then a counter-based hash per number:
        # threefry for each of the 5 * lanes * slots numbers was most of what braking
        # events added to the paper traffic's step.
        s0, s1 = jax.random.bits(jax.random.fold_in(key, 1), (2,), jnp.uint32)
        ctr = jnp.arange(5 * lanes * slots, dtype=jnp.uint32).reshape(5, lanes, slots)
        h = _mix(_mix(ctr ^ s0) + s1)
        return cls(*((h >> 8).astype(jnp.float32) * (1.0 / (1 << 24))))


def _mix(h: Array) -> Array:
    """A bijective 32-bit integer hash (Wellons' ``lowbias32``: full avalanche, bias 0.17)."""
    h = (h ^ (h >> 16)) * jnp.uint32(0x7FEB352D)
    h = (h ^ (h >> 15)) * jnp.uint32(0x846CA68B)
    return h ^ (h >> 16)


def between(u: Array, lo: Array, hi: Array) -> Array:
    """``u`` in [0, 1) mapped to [lo, hi)."""
    return lo + u * (hi - lo)


def episode_value(u: Array, lo: Array, hi: Array, p: EnvParams) -> Array:
    """An episode's value of a range ``[lo, hi]`` from ``u`` in [0, 1): U(lo, hi), but the
    share ``p.range_edge_share`` of the episodes at the ends, half at ``lo``, half at ``hi``:
    a range's ends are its hardest cases, which a uniform draw seldom comes near."""
    q = p.range_edge_share
    if q > 0.0:  # static: off, the uniform draw's program is unchanged
        u = jnp.clip((u - 0.5 * q) / (1.0 - q), 0.0, 1.0)
    return between(u, lo, hi)
