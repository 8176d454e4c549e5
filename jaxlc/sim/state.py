"""The simulator's types: its parameters (``EnvParams``), its state (``Traffic``, ``Ego``,
``EnvState``), the ego's phases and a step's random draws.

``EnvParams`` is ``EnvConfig`` in SI units. Its fields are not declared twice: every
``EnvConfig`` field becomes one, through ``CONVERSIONS`` (the unit changes), ``STATIC`` (the
fields that fix array shapes) and ``DERIVED`` (config fields that become other fields: the
warm-up's time a number of steps, the curvature's number or range four fields, the reward
terms' names the terms). A new simulator setting is added to ``EnvConfig`` alone.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.config import ConfigError, DDPGConfig, EnvConfig
from jaxlc.sim import gap, reward

WAIT, CRUISE, GAP, RL = 0, 1, 2, 3
PHASES = ("wait", "cruise", "gap", "rl")
ACT_DIM = 1  # the paper's action: the yaw acceleration alone (env.longitudinal = "idm")
# Each action entry's sign under the reflection y -> -y: the yaw acceleration flips, the
# longitudinal acceleration (env.longitudinal = "policy") does not.
ACTION_MIRROR = (-1.0, 1.0)
KMH = 1.0 / 3.6

# An EnvConfig field (in the config's units) -> its EnvParams value (SI); any field not named
# here is taken as it is.
CONVERSIONS: dict[str, Callable[[Any], Any]] = {
    "entry_speed_min": lambda v: v * KMH,
    "entry_speed_max": lambda v: v * KMH,
    "desired_speed_min": lambda v: v * KMH,
    "desired_speed_max": lambda v: v * KMH,
    "inflow_min": lambda v: v / 3600.0,  # veh/h -> veh/s
    "inflow_max": lambda v: v / 3600.0,
    "braking_rate": lambda v: v / 3600.0,  # per vehicle-hour -> per vehicle-second
}
# Fields that fix array shapes or loop lengths: static (``pytree_node=False``), so a change
# compiles a new program; every other field is traced and may differ between vmapped models.
STATIC = frozenset({"lanes", "slots_per_lane", "longitudinal", "assist", "mobil", "braking"})
# EnvConfig fields that EnvParams holds as other fields, declared in the class below.
DERIVED = frozenset({"warmup_time", "curvature", "reward_terms"})

_C = EnvConfig()


def _same(v: Any) -> Any:
    return v


def _with_env_config_fields(cls: type) -> type:
    """Declare on ``cls``, before its own fields, one field per ``EnvConfig`` field (less
    ``DERIVED``), with the config's default converted."""
    declared: dict[str, Any] = {}
    for f in dataclasses.fields(EnvConfig):
        if f.name in DERIVED:
            continue
        default = CONVERSIONS.get(f.name, _same)(f.default)
        declared[f.name] = f.type
        if f.name in STATIC:
            default = flax.struct.field(pytree_node=False, default=default)
        setattr(cls, f.name, default)
    cls.__annotations__ = {**declared, **cls.__annotations__}
    return cls


def action_dim(p: Any) -> int:
    """The action's length under ``p`` (an ``EnvParams`` or ``EnvConfig``): 1, the yaw
    acceleration; 2 with ``longitudinal = "policy"``, then the longitudinal one."""
    return 2 if p.longitudinal == "policy" else 1


def curvature_range(value: float | tuple[float, float]) -> tuple[float, float]:
    """``(min, max)`` of a config's ``env.curvature``: a number (a constant road) or a range."""
    if isinstance(value, tuple | list):
        return float(value[0]), float(value[1])
    return float(value), float(value)


@flax.struct.dataclass
@_with_env_config_fields
class EnvParams:
    """Simulator parameters in SI units (speeds m/s, inflow veh/s): every ``EnvConfig`` field
    (``jaxlc/config.py`` documents them), converted by ``CONVERSIONS``, and the fields below.

    Static fields (``STATIC`` and those marked here) fix array shapes and loop lengths; every
    other field is traced, so models with different values (e.g. the action-update step ``k``,
    or a task randomised per env) can share one compiled program under ``vmap``.
    """

    warmup_steps: int = flax.struct.field(
        pytree_node=False, default=int(round(_C.warmup_time / _C.dt))
    )
    # The road's curvature (1/m, > 0 bends toward +y): the constant ``curvature``, or, when
    # ``curvature_drawn`` (static: it adds a leaf to the state), one drawn per episode from
    # U(curvature_min, curvature_max) as the ego spawns and kept in ``EnvState.curvature``.
    curvature: float = 0.0
    curvature_min: float = 0.0
    curvature_max: float = 0.0
    curvature_drawn: bool = flax.struct.field(pytree_node=False, default=False)
    # The reward's terms (``reward.Term``), summed; static: each is a function.
    reward_terms: tuple[reward.Term, ...] = flax.struct.field(
        pytree_node=False, default=reward.PAPER
    )
    gamma: float = DDPGConfig().gamma
    k: int = 1

    @classmethod
    def from_config(
        cls, env: EnvConfig, gamma: float = DDPGConfig().gamma, k: int = 1
    ) -> EnvParams:
        """Convert a validated ``EnvConfig`` (km/h, veh/h) to SI params."""
        values = {
            f.name: CONVERSIONS.get(f.name, _same)(getattr(env, f.name))
            for f in dataclasses.fields(EnvConfig)
            if f.name not in DERIVED
        }
        values["warmup_steps"] = int(round(env.warmup_time / env.dt))
        lo, hi = curvature_range(env.curvature)
        values["curvature"] = lo if lo == hi else 0.5 * (lo + hi)
        values["curvature_min"], values["curvature_max"] = lo, hi
        values["curvature_drawn"] = lo < hi
        try:
            values["reward_terms"] = reward.lookup(env.reward_terms)
        except KeyError as e:
            raise ConfigError(f"config key 'env.reward_terms': {e.args[0]}") from None
        return cls(**values, gamma=gamma, k=k)


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
    per vehicle slot: drawn from ``fold_in(step key, 1)`` only with ``env.mobil`` or
    ``env.braking``, so the paper's traffic draws exactly what it drew before."""

    lc_fire: Array  # acts on an allowed lane change this step (< 1 - exp(-mobil_rate*dt))
    lc_time: Array  # the lane change's duration in [lane_change_time_min, _max)
    brake_fire: Array  # a braking event starts (< 1 - exp(-braking_rate*dt))
    brake_acc: Array  # its deceleration in [braking_decel_min, _max)
    brake_time: Array  # its duration in [braking_time_min, _max)

    @classmethod
    def draw(cls, key: Array, lanes: int, slots: int) -> TrafficDraws:
        u = jax.random.uniform(jax.random.fold_in(key, 1), (5, lanes, slots))
        return cls(*u)


def between(u: Array, lo: Array, hi: Array) -> Array:
    """``u`` in [0, 1) mapped to [lo, hi)."""
    return lo + u * (hi - lo)
