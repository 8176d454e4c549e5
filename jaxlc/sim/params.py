"""The simulator's settings, each declared once, in ``EnvParams``'s class body.

A field declared with ``setting`` is a key of a config's ``[env]`` table: its default and
bounds in the unit the file is written in (``unit``), ``si`` (the conversion to the SI value
the simulator holds, when the units differ) and whether it is static (it fixes shapes or loop
lengths: not a pytree leaf, so a change compiles a new program) or traced (it may differ
between vmapped models). ``jaxlc.config`` reads the same declaration: its ``EnvConfig`` is these
keys in the file's units, validated against the bounds; ``EnvParams.from_config`` (what
``jaxlc.make`` calls) turns one into params. A field declared with ``derived`` is no key: it is
read from the table (``warmup_steps`` from ``warmup_time / dt``, the curvature's range) or
handed in by the learner (``gamma``, ``k``).

    params = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma, k=1)
    params = EnvParams()                       # the defaults: configs/default.toml's [env]
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from typing import Any

import flax.struct

from jaxlc.sim import reward

KMH = 1.0 / 3.6  # m/s per km/h
GAMMA = 0.98  # eq. (11)'s discount unless the learner hands its own (``ddpg.gamma``)


class ConfigError(ValueError):
    """A config value is not allowed; the message names the key and the allowed values.

    ``jaxlc.config.ConfigError``: declared here, beside the settings whose reading raises it,
    so that this module imports no config (``jaxlc.config`` imports it)."""


def kmh(v: float) -> float:
    """km/h -> m/s"""
    return v * KMH


def per_hour(v: float) -> float:
    """per hour -> per second"""
    return v / 3600.0


def curvature_range(value: float | tuple[float, float]) -> tuple[float, float]:
    """``(min, max)`` of a config value that is a number (a constant) or a range, e.g.
    ``env.curvature``."""
    if isinstance(value, tuple | list):
        return float(value[0]), float(value[1])
    return float(value), float(value)


value_range = curvature_range  # any key declared with ``ranged``


def ranged(si: Callable[[Any], Any] = lambda v: v) -> dict[str, Any]:
    """A ``setting``'s arguments for a key that is a number or a range ``[min, max]`` drawn
    per episode from U(min, max) (``EnvParams.drawn``): the field holds ``si`` of the number,
    or of the range's middle, which the episode's draw replaces (``jaxlc.sim.env``)."""
    return dict(toml=float | tuple[float, float], si=lambda v: si(_constant_curvature(v)))


def _ranges(env: Any) -> tuple[tuple[float, float], ...]:
    """``(min, max)`` in SI of each key of ``_drawn(env)``, in its order."""
    fields = {f.name: f for f in dataclasses.fields(EnvParams)}
    convert = {n: fields[n].metadata["si"] for n in _drawn(env)}
    return tuple(tuple(convert[n](v) for v in value_range(getattr(env, n))) for n in convert)


def _drawn(env: Any) -> tuple[str, ...]:
    """The keys given as a range (min < max): drawn per episode."""
    return tuple(
        n for n in RANGED if value_range(getattr(env, n))[0] < value_range(getattr(env, n))[1]
    )


def _constant_curvature(value: float | tuple[float, float]) -> float:
    """The constant road's curvature, or the middle of a drawn one's range."""
    lo, hi = curvature_range(value)
    return lo if lo == hi else 0.5 * (lo + hi)


def setting(
    default: Any,
    lo: float | None = None,
    hi: float | None = None,
    *,
    unit: str,
    doc: str = "",
    open_lo: bool = False,
    static: bool = False,
    si: Callable[[Any], Any] | None = None,
    choices: tuple[str, ...] = (),
    key: str | None = None,
    toml: Any = None,
    read: Callable[[Any], Any] | None = None,
    value: Any = None,
) -> Any:
    """A key of ``[env]`` and its field: ``default`` in ``unit`` (the file's), allowed when
    ``lo <= v <= hi`` (``lo < v`` when ``open_lo``) or one of ``choices``; the field holds
    ``si(v)`` (``v`` when ``si`` is None). ``key``/``toml``: the key's name and type where they
    are not the field's; ``read``: the field from the whole table (``value`` its default).
    ``unit`` "" is a count, a flag, a name or a pure number (a reward weight: per unit of its
    term, the ``doc``)."""
    convert = si or _same
    meta = dict(key=key, default=default, lo=lo, hi=hi, open_lo=open_lo, unit=unit, doc=doc)
    meta.update(static=static, si=convert, choices=choices, toml=toml, read=read)
    value = convert(default) if value is None else value
    return flax.struct.field(pytree_node=not static, default=value, metadata=meta)


def derived(value: Any, read: Callable[[Any], Any] | None, *, unit: str, static: bool) -> Any:
    """A field that is no key: ``read`` from the ``[env]`` table, or handed in (``read`` None)."""
    meta = dict(unit=unit, static=static, read=read)
    return flax.struct.field(pytree_node=not static, default=value, metadata=meta)


def _same(v: Any) -> Any:
    return v


def _warmup_steps(env: Any) -> int:
    return int(round(env.warmup_time / env.dt))


def _curvature_drawn(env: Any) -> bool:
    lo, hi = curvature_range(env.curvature)
    return lo < hi


def _mobil_deciders(env: Any) -> int:
    rate = value_range(env.mobil_rate)[1]  # a drawn rate's highest
    return deciders(env.lanes * env.slots_per_lane, -math.expm1(-rate * env.dt))


@flax.struct.dataclass
class EnvParams:
    """Simulator parameters in SI units (speeds m/s, inflow veh/s); the static fields
    (``STATIC``) fix shapes, every other one is traced (vmappable over models or tasks)."""

    # road, traffic
    road_length: float = setting(600.0, 50.0, unit="m", open_lo=True)
    lanes: int = setting(
        3, 2, 8, unit="", static=True, doc="the ego's way; it starts on lanes // 2"
    )
    lane_width: float = setting(3.7, 2.0, 6.0, unit="m", **ranged())
    # The road's curvature (> 0 bends toward the higher lanes): the constant, or with a range
    # the middle of it; each episode then draws its own (``curvature_drawn``).
    curvature: float = setting(
        0.0,
        -0.01,
        0.01,
        unit="1/m",
        toml=float | tuple[float, float],
        si=_constant_curvature,
        doc="a state input: a number (a constant road) or [min, max], drawn per episode from "
        "U(min, max)",
    )
    range_edge_share: float = setting(
        0.0,
        0.0,
        0.9,
        unit="",
        static=True,  # on, it adds the draw's map to the program
        doc="of the episodes, the share whose drawn value of a range (each key given as "
        "[min, max], the curvature's too) is one of its ends, half each; 0: U(min, max)",
    )
    dt: float = setting(0.1, 0.0, 1.0, unit="s", open_lo=True)
    vehicle_length: float = setting(5.0, 1.0, 20.0, unit="m")
    vehicle_width: float = setting(1.8, 1.0, 3.0, unit="m")
    entry_speed_min: float = setting(0.0, 0.0, 200.0, unit="km/h", **ranged(kmh))
    entry_speed_max: float = setting(40.0, 0.0, 200.0, unit="km/h", **ranged(kmh))
    # Below 10 km/h an ego crawls: at 5 km/h no gap is ever accepted (tests/test_ranges.py).
    desired_speed_min: float = setting(80.0, 10.0, 250.0, unit="km/h", **ranged(kmh))
    desired_speed_max: float = setting(120.0, 10.0, 250.0, unit="km/h", **ranged(kmh))
    # The ego is the next vehicle to enter the middle lane: at 60 veh/h it waits a minute on
    # average, and far fewer would leave episodes waiting past the decision loop's cap.
    inflow_min: float = setting(800.0, 60.0, 4000.0, unit="veh/h per lane", **ranged(per_hour))
    inflow_max: float = setting(1600.0, 60.0, 4000.0, unit="veh/h per lane", **ranged(per_hour))
    slots_per_lane: int = setting(16, 2, 256, unit="", static=True, doc="vehicle slots per lane")
    warmup_steps: int = setting(
        40.0,
        0.0,
        600.0,
        unit="s",
        key="warmup_time",
        toml=float,
        static=True,
        read=_warmup_steps,
        value=400,
        doc="of traffic simulated by reset(); held as round(warmup_time / dt) steps",
    )
    # IDM [S]
    idm_a_max: float = setting(1.5, 0.0, 10.0, unit="m/s^2", open_lo=True)
    idm_b: float = setting(2.0, 0.0, 10.0, unit="m/s^2", open_lo=True)
    idm_time_headway: float = setting(1.5, 0.0, 5.0, unit="s", open_lo=True)
    idm_s0: float = setting(2.0, 0.0, 20.0, unit="m")
    idm_delta: float = setting(4.0, 1.0, 10.0, unit="")
    idm_b_max: float = setting(9.0, 0.0, 20.0, unit="m/s^2", open_lo=True, doc="braking clip")
    # episode
    p_yield: float = setting(0.5, 0.0, 1.0, unit="")
    command_distance: float = setting(80.0, 0.0, 400.0, unit="m", doc="before the command")
    gap_time_limit: float = setting(5.0, 0.0, 60.0, unit="s", open_lo=True, doc="to find a gap")
    gap_x_limit: float = setting(450.0, 0.0, unit="m", open_lo=True, doc="no gap beyond this x")
    gap_time_headway: float = setting(
        0.5, 0.0, 5.0, unit="s", doc="T in s0 + T*v of gap acceptance"
    )
    b_safe: float = setting(
        4.0, 0.0, 20.0, unit="m/s^2", open_lo=True, doc="lag deceleration bound"
    )
    gap_min_ttc: float = setting(
        4.0,
        0.0,
        20.0,
        unit="s",
        doc="least time-to-collision (margin s0) of the gap's lead and lag",
    )
    # ego lateral
    max_yaw_acc: float = setting(
        0.5, 0.0, 10.0, unit="rad/s^2", open_lo=True, doc="A in a_lat = A*action"
    )
    manoeuvre_time_limit: float = setting(10.0, 0.0, 120.0, unit="s", open_lo=True)
    # A limit that follows the speed (issue 79: lane changes in jams at 0-9 m/s time out);
    # static, so off (0) compiles today's program.
    manoeuvre_distance: float = setting(
        0.0,
        0.0,
        10000.0,
        unit="m",
        static=True,
        doc="0 (off: every manoeuvre has manoeuvre_time_limit) or D: a manoeuvre at speed v "
        "(now) times out after clip(D / v, manoeuvre_time_limit, manoeuvre_time_max) s",
    )
    manoeuvre_time_max: float = setting(
        30.0, 0.0, 120.0, unit="s", open_lo=True, static=True, doc="with manoeuvre_distance on"
    )
    terminal_timeout: bool = setting(
        False,
        unit="",
        doc="true: a timeout is terminal and the manoeuvre time is observed; false: it "
        "truncates (the learner bootstraps) and the time is not observed (obs[6] = 0)",
    )
    border: float = setting(3.7, 0.0, 20.0, unit="m", open_lo=True, doc="D (paper: = lane width)")
    success_offset: float = setting(0.2, 0.0, unit="m", open_lo=True)
    success_heading: float = setting(0.02, 0.0, unit="rad", open_lo=True)
    success_yaw_rate: float = setting(0.02, 0.0, unit="rad/s", open_lo=True)
    # reward, eqs. (8)-(11) (gamma is ddpg.gamma): each weight in reward per unit of its term
    w1: float = setting(10.0, 0.0, unit="")
    w2: float = setting(5.0, 0.0, unit="")
    w3: float = setting(0.075, 0.0, unit="")
    w4: float = setting(1.0, 0.0, unit="")
    # The whole manoeuvre's terms (reward.MANOEUVRE: r_long, r_lat, r_gap, r_speed), [D], off
    # until named in reward_terms; their weights and the norms they read.
    w_long_acc: float = setting(
        0.0, 0.0, unit="", doc="r_long: per m/s^2 of |longitudinal acceleration|"
    )
    w_long_jerk: float = setting(0.0, 0.0, unit="", doc="r_long: per m/s^3 of |longitudinal jerk|")
    w_lat_acc: float = setting(
        0.0, 0.0, unit="", doc="r_lat: per m/s^2 of |v*omega| past lat_acc_max"
    )
    w_lat_jerk: float = setting(0.0, 0.0, unit="", doc="r_lat: per m/s^3 of jerk past lat_jerk_max")
    lat_acc_max: float = setting(3.0, 0.0, unit="m/s^2", open_lo=True, doc="ISO 11270's bound")
    lat_jerk_max: float = setting(5.0, 0.0, unit="m/s^3", open_lo=True, doc="ISO 11270's bound")
    w_headway: float = setting(0.0, 0.0, unit="", doc="r_gap: per s of headway under headway_min")
    headway_min: float = setting(0.9, 0.0, unit="s", doc="the critical time headway")
    w_speed: float = setting(0.0, 0.0, unit="", doc="r_speed: per unit of |v - v0| / v0")
    reward_scale: float = setting(
        1.0, 0.0, unit="", open_lo=True, doc="multiplies every reward term"
    )
    reward_terms: tuple[reward.Term, ...] = setting(
        ("r_s", "r_e", "r_d"),
        unit="",
        static=True,  # each is a function
        toml=tuple[str, ...],
        si=reward.lookup,
        doc="the reward's terms by name, summed: the paper's r_s, r_e, r_d (jaxlc.sim.reward) "
        "and any registered with jaxlc.sim.reward.register",
    )
    # observation, the ego's longitudinal control ([D], the paper's future work), the assist
    offset_obs_scale: float = setting(
        3.7, 0.0, 100.0, unit="m", open_lo=True, doc="per unit of obs dd"
    )
    yaw_rate_obs: str = setting(
        "absolute",
        unit="",
        static=True,
        choices=("absolute", "lane"),
        doc="obs[3]: the ego's yaw rate ('absolute', the paper's) or its yaw rate relative to "
        "its lane's ('lane': 0 holds the lane on a bend, as the success test reads it)",
    )
    longitudinal: str = setting(
        "idm",
        unit="",
        static=True,
        choices=("idm", "policy"),
        doc="'idm' (the paper's: IDM with adaptation to the target lane's lead; the action is "
        "the yaw acceleration alone) or 'policy' (a second action entry u adds "
        "long_acc_bound*u to that IDM acceleration, within [-idm_b_max, idm_a_max] and never "
        "past the ego's desired speed)",
    )
    long_acc_bound: float = setting(
        2.0, 0.0, 10.0, unit="m/s^2", open_lo=True, doc="the policy's longitudinal authority"
    )
    assist: str = setting(
        "none",
        unit="",
        static=True,
        choices=("none", "fitting", "fitting_hold"),
        doc="'none' (the policy's action is executed) or 'fitting' (a driver-assist layer adds "
        "jaxlc.sim.controller.fitting_action, which holds the origin lane and adjusts the "
        "speed until the gap fits the headway norm, to the policy's action in the RL phase: "
        "the policy learns a residual on it), or 'fitting_hold' (the same, but while the "
        "assist holds the origin lane its lateral action is executed alone)",
    )
    assist_authority: float = setting(
        1.0,
        0.0,
        1.0,
        unit="",
        doc="with an assist, the share of each action bound the policy's residual may take: "
        "the executed action is clip(assist + assist_authority * action)",
    )
    operating_speed: tuple[float, ...] = setting(
        (),
        unit="km/h",
        static=True,  # on, it adds the check to the program
        toml=tuple[float, ...],
        si=lambda v: tuple(kmh(x) for x in v),
        doc="[] (off: every command is taken) or [min, max]: the ego's speeds at the command "
        "and when its gap is found within which a lane change is taken (UN R79, ACSF "
        "category C: [60, 130]); a command, or a gap found, outside it ends the episode as "
        "'declined', counted apart from the failures",
    )
    # Traffic that cuts in and brakes ([D], SPEC "Beyond the paper"): off in the paper's
    # traffic. The switches are static (they add state); every number below is traced.
    mobil: bool = setting(
        False,
        unit="",
        static=True,
        doc="true: the other vehicles change lanes by MOBIL on the IDM (jaxlc.sim.mobil); "
        "false: they keep their lane (the paper's traffic)",
    )
    mobil_politeness: float = setting(
        0.2, 0.0, 1.0, unit="", doc="MOBIL's p: weight of the others' gain", **ranged()
    )
    mobil_threshold: float = setting(
        0.1, 0.0, 5.0, unit="m/s^2", doc="MOBIL's switching threshold", **ranged()
    )
    mobil_bias_right: float = setting(
        0.0,
        -2.0,
        2.0,
        unit="m/s^2",
        doc="added to the incentive toward the lower lanes (the right), taken from the one "
        "toward the left; 0 keeps the traffic symmetric under the road's reflection",
    )
    mobil_rate: float = setting(
        0.5,
        0.0,
        10.0,
        unit="1/s",
        open_lo=True,
        doc="a driver acts on an allowed lane change at this rate (a drawn latency)",
        **ranged(),
    )
    mobil_interval: float = setting(
        10.0, 0.0, 600.0, unit="s", doc="least time between a vehicle's lane change starts"
    )
    lane_change_time_min: float = setting(
        3.0, 0.5, 20.0, unit="s", doc="a lane change lasts U(min, max)"
    )
    lane_change_time_max: float = setting(6.0, 0.5, 20.0, unit="s")
    braking: bool = setting(
        False,
        unit="",
        static=True,
        doc="true: every vehicle brakes hard now and then (a Poisson process, "
        "jaxlc.sim.braking); false: only for its leader (the paper's traffic)",
    )
    braking_rate: float = setting(
        2.0,
        0.0,
        3600.0,
        unit="per vehicle-hour",
        doc="braking events (Poisson)",
        **ranged(per_hour),
    )
    braking_decel_min: float = setting(
        3.0, 0.0, 9.0, unit="m/s^2", doc="an event brakes at U(min, max)"
    )
    braking_decel_max: float = setting(
        7.0, 0.0, 9.0, unit="m/s^2", doc="at most the IDM's idm_b_max"
    )
    braking_time_min: float = setting(1.0, 0.1, 60.0, unit="s", doc="an event lasts U(min, max)")
    braking_time_max: float = setting(3.0, 0.1, 60.0, unit="s")
    # --- no keys: read from the table above, or handed in by the learner
    # The most drivers of one env that weigh a lane change on one step (``mobil.decide``) at the
    # config's mobil_rate, so that more act on one step with probability under 1e-6 even with
    # every slot filled (a batch of traffics with traced rates should carry its highest rate's).
    mobil_deciders: int = derived(12, _mobil_deciders, unit="", static=True)
    # A drawn curvature's range, U(curvature_min, curvature_max), drawn as the ego spawns and
    # kept in ``EnvState.curvature`` when ``curvature_drawn`` (static: it adds a state leaf).
    curvature_min: float = derived(
        0.0, lambda env: curvature_range(env.curvature)[0], unit="1/m", static=False
    )
    curvature_max: float = derived(
        0.0, lambda env: curvature_range(env.curvature)[1], unit="1/m", static=False
    )
    curvature_drawn: bool = derived(False, _curvature_drawn, unit="", static=True)
    # The keys of ``RANGED`` given as a range (static: they add ``EnvState.episode``) and their
    # ranges in SI; each episode draws its own values, which replace the fields' (``env``).
    drawn: tuple[str, ...] = derived((), _drawn, unit="", static=True)
    ranges: tuple[tuple[float, float], ...] = derived((), _ranges, unit="", static=False)
    gamma: float = derived(GAMMA, None, unit="", static=False)  # eq. (11)'s discount
    k: int = derived(1, None, unit="", static=False)  # an action is held for k RL steps
    # The source of the traffic's draws: None, the traffic's own (no leaf: the nominal
    # programs are unchanged); a proposal's (``jaxlc.evaluation.proposal``) draws them tilted.
    draws: Any = derived(None, None, unit="", static=False)

    @classmethod
    def from_config(cls, env: Any, gamma: float = GAMMA, k: int = 1) -> EnvParams:
        """A validated ``EnvConfig`` (the ``[env]`` table in its units) as params, with the
        learner's ``gamma`` and ``k``; an unknown reward term raises ``ConfigError``."""
        values: dict[str, Any] = {"gamma": gamma, "k": k}
        for f in dataclasses.fields(cls):
            m = f.metadata
            if m["read"] is not None:
                values[f.name] = m["read"](env)
            elif "key" in m:
                key = m["key"] or f.name
                try:
                    values[f.name] = m["si"](getattr(env, key))
                except KeyError as e:
                    raise ConfigError(f"config key 'env.{key}': {e.args[0]}") from None
        return cls(**values)


def settings() -> tuple[dataclasses.Field, ...]:
    """``EnvParams``' fields that are keys of ``[env]``, in their order."""
    return tuple(f for f in dataclasses.fields(EnvParams) if "key" in f.metadata)


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


# The keys that may be a range [min, max], drawn per episode (besides ``curvature``, whose
# draw is the road's own: ``curvature_drawn``).
RANGED = (
    "lane_width",
    "entry_speed_min",
    "entry_speed_max",
    "desired_speed_min",
    "desired_speed_max",
    "inflow_min",
    "inflow_max",
    "mobil_politeness",
    "mobil_threshold",
    "mobil_rate",
    "braking_rate",
)

# The fields that fix array shapes or loop lengths (declared ``static`` above).
STATIC = frozenset(
    f.name for f in dataclasses.fields(EnvParams) if not f.metadata.get("pytree_node", True)
)
