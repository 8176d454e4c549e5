"""The simulator's parameters, ``EnvParams``: ``EnvConfig`` (``jaxlc/config.py``, which
documents each field) in SI units, and the values derived from it.

    params = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma, k=1)
    params = EnvParams()                       # the defaults: configs/default.toml's [env]

Every ``EnvConfig`` field but ``DERIVED`` is a field here of the same name, converted by
``CONVERSIONS`` where its unit differs; ``tests/test_params.py`` holds the two in step (names
and defaults), so a new simulator setting is a field of both.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import flax.struct

from jaxlc.config import ConfigError, EnvConfig
from jaxlc.sim import reward

KMH = 1.0 / 3.6  # m/s per km/h
GAMMA = 0.98  # eq. (11)'s discount unless the learner hands its own (``ddpg.gamma``)

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
# EnvConfig fields that EnvParams holds as other fields (``from_config``).
DERIVED = frozenset({"warmup_time", "curvature", "reward_terms"})


def _static(default: Any) -> Any:
    """A field that fixes array shapes or loop lengths: not a leaf, so a change compiles a new
    program; every other field is traced and may differ between vmapped models."""
    return flax.struct.field(pytree_node=False, default=default)


def _same(v: Any) -> Any:
    return v


def curvature_range(value: float | tuple[float, float]) -> tuple[float, float]:
    """``(min, max)`` of a config's ``env.curvature``: a number (a constant road) or a range."""
    if isinstance(value, tuple | list):
        return float(value[0]), float(value[1])
    return float(value), float(value)


@flax.struct.dataclass
class EnvParams:
    """Simulator parameters in SI units (speeds m/s, inflow veh/s); the static fields
    (``STATIC``) fix shapes, every other one is traced (vmappable over models or tasks)."""

    # road, traffic
    road_length: float = 600.0
    lanes: int = _static(3)
    lane_width: float = 3.7
    dt: float = 0.1
    vehicle_length: float = 5.0
    vehicle_width: float = 1.8
    entry_speed_min: float = 0.0 * KMH  # m/s
    entry_speed_max: float = 40.0 * KMH  # m/s
    desired_speed_min: float = 80.0 * KMH  # m/s
    desired_speed_max: float = 120.0 * KMH  # m/s
    inflow_min: float = 800.0 / 3600.0  # veh/s per lane
    inflow_max: float = 1600.0 / 3600.0  # veh/s per lane
    slots_per_lane: int = _static(16)
    # IDM [S]
    idm_a_max: float = 1.5
    idm_b: float = 2.0
    idm_time_headway: float = 1.5
    idm_s0: float = 2.0
    idm_delta: float = 4.0
    idm_b_max: float = 9.0
    # episode
    p_yield: float = 0.5
    command_distance: float = 80.0
    gap_time_limit: float = 5.0
    gap_x_limit: float = 450.0
    gap_time_headway: float = 0.5
    b_safe: float = 4.0
    gap_min_ttc: float = 4.0
    # ego lateral
    max_yaw_acc: float = 0.5
    manoeuvre_time_limit: float = 10.0
    terminal_timeout: bool = False
    border: float = 3.7
    success_offset: float = 0.2
    success_heading: float = 0.02
    success_yaw_rate: float = 0.02
    # reward, eqs. (8)-(11), and the whole manoeuvre's terms (reward.MANOEUVRE)
    w1: float = 10.0
    w2: float = 5.0
    w3: float = 0.075
    w4: float = 1.0
    w_long_acc: float = 0.0
    w_long_jerk: float = 0.0
    w_lat_acc: float = 0.0
    w_lat_jerk: float = 0.0
    lat_acc_max: float = 3.0
    lat_jerk_max: float = 5.0
    w_headway: float = 0.0
    headway_min: float = 0.9
    w_speed: float = 0.0
    reward_scale: float = 1.0
    # observation, the ego's longitudinal control, the driver assist
    offset_obs_scale: float = 3.7
    longitudinal: str = _static("idm")
    long_acc_bound: float = 2.0
    assist: str = _static("none")
    assist_authority: float = 1.0
    # traffic that cuts in and brakes
    mobil: bool = _static(False)
    mobil_politeness: float = 0.2
    mobil_threshold: float = 0.1
    mobil_bias_right: float = 0.0
    mobil_rate: float = 0.5
    mobil_interval: float = 10.0
    lane_change_time_min: float = 3.0
    lane_change_time_max: float = 6.0
    braking: bool = _static(False)
    braking_rate: float = 2.0 / 3600.0  # per vehicle-second
    braking_decel_min: float = 3.0
    braking_decel_max: float = 7.0
    braking_time_min: float = 1.0
    braking_time_max: float = 3.0
    # derived from EnvConfig's DERIVED fields
    warmup_steps: int = _static(400)  # round(warmup_time / dt)
    # The most drivers of one env that weigh a lane change on one step (``mobil.decide``):
    # ``deciders`` at the config's mobil_rate, so that more act on one step with probability
    # under 1e-6 even with every slot filled (a batch of traffics with traced rates should
    # carry its highest rate's).
    mobil_deciders: int = _static(12)
    # The road's curvature (1/m, > 0 bends toward +y): the constant ``curvature``, or, when
    # ``curvature_drawn`` (static: it adds a leaf to the state), one drawn per episode from
    # U(curvature_min, curvature_max) as the ego spawns and kept in ``EnvState.curvature``.
    curvature: float = 0.0
    curvature_min: float = 0.0
    curvature_max: float = 0.0
    curvature_drawn: bool = _static(False)
    # The reward's terms (``reward.Term``), summed; static: each is a function.
    reward_terms: tuple[reward.Term, ...] = _static(reward.PAPER)
    # handed in by the learner
    gamma: float = GAMMA  # the discount of eq. (11)'s out-of-bounds penalty
    k: int = 1  # the action-update step: an action is held for k RL steps

    @classmethod
    def from_config(cls, env: EnvConfig, gamma: float = GAMMA, k: int = 1) -> EnvParams:
        """A validated ``EnvConfig`` (km/h, veh/h) as SI params, with the learner's ``gamma``
        and ``k``; an unknown reward term raises ``ConfigError``."""
        values = {
            f.name: CONVERSIONS.get(f.name, _same)(getattr(env, f.name))
            for f in dataclasses.fields(EnvConfig)
            if f.name not in DERIVED
        }
        values["warmup_steps"] = int(round(env.warmup_time / env.dt))
        values["mobil_deciders"] = deciders(
            env.lanes * env.slots_per_lane, -math.expm1(-env.mobil_rate * env.dt)
        )
        lo, hi = curvature_range(env.curvature)
        values["curvature"] = lo if lo == hi else 0.5 * (lo + hi)
        values["curvature_min"], values["curvature_max"] = lo, hi
        values["curvature_drawn"] = lo < hi
        try:
            values["reward_terms"] = reward.lookup(env.reward_terms)
        except KeyError as e:
            raise ConfigError(f"config key 'env.reward_terms': {e.args[0]}") from None
        return cls(**values, gamma=gamma, k=k)


def deciders(n: int, q: float, tail: float = 1e-6) -> int:
    """The least ``k`` with P(Binomial(n, q) > k) <= ``tail``: of ``n`` drivers each acting
    with probability ``q`` on a step, more than ``k`` act on one step that rarely."""
    if q <= 0.0:
        return 1
    if q >= 1.0:
        return n

    def pmf(j: int) -> float:
        log_comb = math.lgamma(n + 1) - math.lgamma(j + 1) - math.lgamma(n - j + 1)
        return math.exp(log_comb + j * math.log(q) + (n - j) * math.log1p(-q))

    k, above = n, 0.0  # above: P(more than k act)
    while k > 1 and above + pmf(k) <= tail:
        above += pmf(k)
        k -= 1
    return k


# The fields that fix array shapes or loop lengths (declared with ``_static`` above).
STATIC = frozenset(
    f.name for f in dataclasses.fields(EnvParams) if not f.metadata.get("pytree_node", True)
)
