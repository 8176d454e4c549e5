"""Typed, frozen configuration loaded from TOML and validated once, at the edge.

A config file has four tables, ``[env]``, ``[ddpg]``, ``[train]`` and ``[grid]``; every field
below is a key of its table. ``configs/default.toml`` holds the dataclasses' defaults, the
built-in default of ``python -m jaxlc.sweep``; ``configs/paper.toml`` the paper's method as
written. Overrides are ``table.key=value`` strings (TOML syntax for the value).

Any problem (unknown table or key, wrong type, value out of range) raises ``ConfigError`` with
one line naming the key and what is allowed; nothing is run with a bad config.

This module stays at the top of the package, below every layer: ``jaxlc.sim``, ``learn``,
``study`` and ``evaluation`` may all import it, and it imports no other jaxlc module
(``tests/test_layout.py`` checks both).
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import tomllib
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
PAPER_CONFIG = CONFIG_DIR / "paper.toml"  # the paper's method as written
DEFAULT_CONFIG = CONFIG_DIR / "default.toml"  # the built-in default: the dataclasses' values
# Fewest env-steps one episode can take: the ego must drive command_distance (80 m) from the
# entrance at no more than its entry speed plus IDM acceleration; 50 steps (5 s) is below that.
MIN_EPISODE_STEPS = 50


class ConfigError(ValueError):
    """A config value is not allowed; the message names the key and the allowed values."""


def _f(
    default: Any,
    lo: float | None = None,
    hi: float | None = None,
    *,
    open_lo: bool = False,
    doc: str = "",
) -> Any:
    """A dataclass field with bounds: ``lo <= v <= hi`` (``lo < v`` when ``open_lo``)."""
    meta = {"lo": lo, "hi": hi, "open_lo": open_lo, "doc": doc}
    if isinstance(default, list | tuple):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


@dataclass(frozen=True)
class EnvConfig:
    """Road, traffic, IDM, episode, ego kinematics and reward (docs/usage.md, "The simulator
    in a few lines")."""

    road_length: float = _f(600.0, 50.0, open_lo=True, doc="m")
    lanes: int = _f(3, 2, 8, doc="lanes in the ego's direction; the ego starts on lanes // 2")
    lane_width: float = _f(3.7, 2.0, 6.0, doc="m")
    curvature: float | tuple[float, float] = _f(
        0.0,
        -0.01,
        0.01,
        doc="1/m (> 0 bends toward the higher lanes), a state input: a number (a constant "
        "road) or [min, max], drawn per episode from U(min, max)",
    )
    dt: float = _f(0.1, 0.0, 1.0, open_lo=True, doc="s")
    vehicle_length: float = _f(5.0, 1.0, 20.0)
    vehicle_width: float = _f(1.8, 1.0, 3.0)
    entry_speed_min: float = _f(0.0, 0.0, 200.0, doc="km/h")
    entry_speed_max: float = _f(40.0, 0.0, 200.0, doc="km/h")
    # Below 10 km/h an ego crawls: at 5 km/h no gap is ever accepted (tests/test_ranges.py).
    desired_speed_min: float = _f(80.0, 10.0, 250.0, doc="km/h")
    desired_speed_max: float = _f(120.0, 10.0, 250.0, doc="km/h")
    # The ego is the next vehicle to enter the middle lane: at 60 veh/h it waits a minute on
    # average, and far fewer would leave episodes waiting past the decision loop's cap.
    inflow_min: float = _f(800.0, 60.0, 4000.0, doc="veh/h per lane")
    inflow_max: float = _f(1600.0, 60.0, 4000.0, doc="veh/h per lane")
    slots_per_lane: int = _f(16, 2, 256, doc="static vehicle slots per lane")
    warmup_time: float = _f(40.0, 0.0, 600.0, doc="s of traffic simulated by reset()")
    # IDM [S]
    idm_a_max: float = _f(1.5, 0.0, 10.0, open_lo=True)
    idm_b: float = _f(2.0, 0.0, 10.0, open_lo=True)
    idm_time_headway: float = _f(1.5, 0.0, 5.0, open_lo=True)
    idm_s0: float = _f(2.0, 0.0, 20.0)
    idm_delta: float = _f(4.0, 1.0, 10.0)
    idm_b_max: float = _f(9.0, 0.0, 20.0, open_lo=True, doc="braking clip, m/s^2")
    # episode
    p_yield: float = _f(0.5, 0.0, 1.0)
    command_distance: float = _f(80.0, 0.0, 400.0, doc="m travelled before the command")
    gap_time_limit: float = _f(5.0, 0.0, 60.0, open_lo=True, doc="s to find a gap")
    gap_x_limit: float = _f(450.0, 0.0, open_lo=True, doc="m; no gap beyond this x")
    gap_time_headway: float = _f(0.5, 0.0, 5.0, doc="s in s0 + T*v of gap acceptance")
    b_safe: float = _f(4.0, 0.0, 20.0, open_lo=True, doc="m/s^2, lag deceleration bound")
    gap_min_ttc: float = _f(
        4.0, 0.0, 20.0, doc="s, least time-to-collision (margin s0) of the gap's lead and lag"
    )
    # ego lateral
    max_yaw_acc: float = _f(0.5, 0.0, 10.0, open_lo=True, doc="A in a_lat = A*action, rad/s^2")
    manoeuvre_time_limit: float = _f(10.0, 0.0, 120.0, open_lo=True, doc="s")
    terminal_timeout: bool = _f(
        False,
        doc="true: a timeout is terminal and the manoeuvre time is observed; false: it "
        "truncates (the learner bootstraps) and the time is not observed (obs[6] = 0)",
    )
    border: float = _f(3.7, 0.0, 20.0, open_lo=True, doc="D, m (paper: = lane width)")
    success_offset: float = _f(0.2, 0.0, open_lo=True, doc="m")
    success_heading: float = _f(0.02, 0.0, open_lo=True, doc="rad")
    success_yaw_rate: float = _f(0.02, 0.0, open_lo=True, doc="rad/s")
    # reward, eqs. (8)-(11); gamma is ddpg.gamma
    w1: float = _f(10.0, 0.0)
    w2: float = _f(5.0, 0.0)
    w3: float = _f(0.075, 0.0)
    w4: float = _f(1.0, 0.0)
    # The whole manoeuvre's terms (jaxlc.sim.reward.MANOEUVRE: r_long, r_lat, r_gap, r_speed),
    # [D], off until named in reward_terms; their weights and the norms they read.
    w_long_acc: float = _f(0.0, 0.0, doc="r_long: per m/s^2 of |longitudinal acceleration|")
    w_long_jerk: float = _f(0.0, 0.0, doc="r_long: per m/s^3 of |longitudinal jerk|")
    w_lat_acc: float = _f(0.0, 0.0, doc="r_lat: per m/s^2 of |v*omega| past lat_acc_max")
    w_lat_jerk: float = _f(0.0, 0.0, doc="r_lat: per m/s^3 of lateral jerk past lat_jerk_max")
    lat_acc_max: float = _f(3.0, 0.0, open_lo=True, doc="m/s^2, ISO 11270's bound")
    lat_jerk_max: float = _f(5.0, 0.0, open_lo=True, doc="m/s^3, ISO 11270's bound")
    w_headway: float = _f(0.0, 0.0, doc="r_gap: per s of headway under headway_min")
    headway_min: float = _f(0.9, 0.0, doc="s, the critical time headway")
    w_speed: float = _f(0.0, 0.0, doc="r_speed: per unit of |v - v0| / v0")
    reward_scale: float = _f(1.0, 0.0, open_lo=True, doc="multiplies every reward term")
    reward_terms: tuple[str, ...] = _f(
        ["r_s", "r_e", "r_d"],
        doc="the reward's terms by name, summed: the paper's r_s, r_e, r_d (jaxlc.sim.reward) "
        "and any registered with jaxlc.sim.reward.register",
    )
    offset_obs_scale: float = _f(3.7, 0.0, 100.0, open_lo=True, doc="m per unit of obs dd")
    # The ego's longitudinal control in the RL phase ([D], the paper's future work).
    longitudinal: str = _f(
        "idm",
        doc="'idm' (the paper's: IDM with adaptation to the target lane's lead; the action is "
        "the yaw acceleration alone) or 'policy' (a second action entry u adds "
        "long_acc_bound*u to that IDM acceleration, within [-idm_b_max, idm_a_max] and never "
        "past the ego's desired speed)",
    )
    long_acc_bound: float = _f(
        2.0, 0.0, 10.0, open_lo=True, doc="m/s^2, the policy's longitudinal authority"
    )
    assist: str = _f(
        "none",
        doc="'none' (the policy's action is executed) or 'fitting' (a driver-assist layer adds "
        "jaxlc.sim.controller.fitting_action, which holds the origin lane and adjusts the "
        "speed until the gap fits the headway norm, to the policy's action in the RL phase: "
        "the policy learns a residual on it), or 'fitting_hold' (the same, but while the "
        "assist holds the origin lane its lateral action is executed alone)",
    )
    assist_authority: float = _f(
        1.0,
        0.0,
        1.0,
        doc="with an assist, the share of each action bound the policy's residual may take: "
        "the executed action is clip(assist + assist_authority * action)",
    )
    # Traffic that cuts in and brakes ([D], SPEC "Beyond the paper"): off in the paper's
    # traffic. The switches are static (they add state); every number below is traced.
    mobil: bool = _f(
        False,
        doc="true: the other vehicles change lanes by MOBIL on the IDM (jaxlc.sim.mobil); "
        "false: they keep their lane (the paper's traffic)",
    )
    mobil_politeness: float = _f(0.2, 0.0, 1.0, doc="MOBIL's p: weight of the others' gain")
    mobil_threshold: float = _f(0.1, 0.0, 5.0, doc="MOBIL's switching threshold, m/s^2")
    mobil_bias_right: float = _f(
        0.0,
        -2.0,
        2.0,
        doc="m/s^2 added to the incentive toward the lower lanes (the right), taken from "
        "the one toward the left; 0 keeps the traffic symmetric under the road's reflection",
    )
    mobil_rate: float = _f(
        0.5,
        0.0,
        10.0,
        open_lo=True,
        doc="1/s: a driver acts on an allowed lane change at this rate (a drawn latency)",
    )
    mobil_interval: float = _f(
        10.0, 0.0, 600.0, doc="s, least time between a vehicle's lane change starts"
    )
    lane_change_time_min: float = _f(3.0, 0.5, 20.0, doc="s, a lane change lasts U(min, max)")
    lane_change_time_max: float = _f(6.0, 0.5, 20.0, doc="s")
    braking: bool = _f(
        False,
        doc="true: every vehicle brakes hard now and then (a Poisson process, "
        "jaxlc.sim.braking); false: only for its leader (the paper's traffic)",
    )
    braking_rate: float = _f(
        2.0, 0.0, 3600.0, doc="braking events per vehicle-hour (a Poisson process)"
    )
    braking_decel_min: float = _f(3.0, 0.0, 9.0, doc="m/s^2, an event brakes at U(min, max)")
    braking_decel_max: float = _f(7.0, 0.0, 9.0, doc="m/s^2 (at most the IDM's idm_b_max)")
    braking_time_min: float = _f(1.0, 0.1, 60.0, doc="s, an event lasts U(min, max)")
    braking_time_max: float = _f(3.0, 0.1, 60.0, doc="s")


@dataclass(frozen=True)
class DDPGConfig:
    """Learner hyperparameters (the paper's DDPG; docs/decisions.md)."""

    hidden: tuple[int, ...] = _f([300, 600], 1, 4096)
    actor_lr: float = _f(1e-4, 0.0, 1.0, open_lo=True)
    critic_lr: float = _f(1e-3, 0.0, 1.0, open_lo=True)
    gamma: float = _f(0.98, 0.0, 1.0, open_lo=True)
    tau: float = _f(0.005, 0.0, 1.0, open_lo=True)
    batch_size: int = _f(64, 1, 65536)
    final_init: float = _f(3e-3, 0.0, open_lo=True)
    noise_sigma: float = _f(0.2, 0.0, 2.0)
    noise_clip: float = _f(2.0, 0.0, 10.0, open_lo=True, doc="truncation, in sigmas")
    updates_per_step: int = _f(1, 1, 64, doc="gradient updates per scan step per model")
    updates_per_transition: int = _f(
        0, 0, 8, doc="updates per RL transition (the paper: 1); 0 uses updates_per_step"
    )
    learner: str = _f(
        "ddpg", doc="the learner (jaxlc.learn.learners): 'ddpg' (the paper's) or 'td3'"
    )
    td3_target_noise: float = _f(0.2, 0.0, 2.0, doc="TD3 target smoothing sigma, tanh units")
    td3_target_clip: float = _f(0.5, 0.0, 2.0, doc="TD3 target smoothing noise clip")
    td3_policy_delay: int = _f(2, 1, 100, doc="TD3: critic updates per actor/target update")
    mirror: bool = _f(True, doc="reflect half of each batch across the road's axis")
    mirror_pairs: bool = _f(
        True,
        doc="with mirror: a batch is batch_size/2 transitions and their reflections, so the "
        "odd actor runs its trunk once per row (the plain actor's FLOPs); false reflects "
        "each drawn row with probability 1/2; ignored without mirror",
    )
    huber_delta: float = _f(10.0, 0.0, doc="critic loss Huber at this TD error; 0 = squared")
    symmetric_actor: bool = _f(
        True, doc="actor odd under the road's reflection: mu(s) = (f(s) - f(Ms)) / 2"
    )


@dataclass(frozen=True)
class TrainConfig:
    """The run: parallel envs, episodes, checkpoints, chunks, seeds."""

    envs_per_model: int = _f(32, 1, 65536)
    episodes: int = _f(5000, 1)
    checkpoint_every: int = _f(100, 1)
    chunk_steps: int = _f(150, 1, doc="scan steps between host saves")
    max_steps: int = _f(0, 0, doc="scan-step cap per run; 0 = until every model is done")
    save_every_s: float = _f(60.0, 0.0, doc="s between full-state saves (0: every chunk)")
    seeds: int = _f(1, 1, 1024)
    seed: int = _f(0, 0, 2**31 - 1, doc="the first seed: a run trains seed, seed + 1, ...")
    anneal_from: float = _f(1.0, 0.0, 1.0, doc="fraction of episodes where annealing starts")
    noise_final: float = _f(1.0, 0.0, 1.0, doc="noise sigma multiplier at the last episode")
    lr_final: float = _f(1.0, 0.0, 1.0, doc="learning-rate multiplier at the last episode")


@dataclass(frozen=True)
class GridConfig:
    """Axes of the model grid; the grid is their Cartesian product, in this order.

    ``actor_lr``/``critic_lr``/``noise_sigma`` empty means the ``[ddpg]`` value for every cell.
    """

    k: tuple[int, ...] = _f([1, 2, 4], 1, 1000)
    memory: tuple[int, ...] = _f([2000, 4000, 8000], 1)
    actor_lr: tuple[float, ...] = _f([], 0.0, 1.0, open_lo=True)
    critic_lr: tuple[float, ...] = _f([], 0.0, 1.0, open_lo=True)
    noise_sigma: tuple[float, ...] = _f([], 0.0, 2.0)


@dataclass(frozen=True)
class EvalConfig:
    """The evaluation protocol of ``python -m jaxlc.evaluate`` (whose flags of the same names
    override these): the paper's fixed cases at each checkpoint, then the held-out lane
    changes of each final checkpoint. Not part of ``Config.hash``: it names what was trained."""

    cases: int = _f(100, 1, doc="the paper's lane-change cases per checkpoint")
    max_steps: int = _f(1500, 1, doc="env steps a case may take before it counts unfinished")
    seed: int = _f(0, 0, 2**31 - 1, doc="seed of the cases")
    chunk: int = _f(32, 1, doc="policies per compiled batch")
    traced: int = _f(4, 0, 1000, doc="cases whose trajectories the figures draw")
    lane_changes: int = _f(1000, 0, doc="held-out lane changes per final checkpoint (0: none)")
    heldout_seed: int = _f(0, 0, 2**31 - 1, doc="seed of the held-out cases")
    traffic: tuple[str, ...] = _f(
        [],
        doc='[env] overrides ("env.KEY=VALUE") of the traffic the held-out lane changes are '
        "driven in, when it is not the training's (written to eval/heldout_traffic/)",
    )


@dataclass(frozen=True)
class Config:
    env: EnvConfig = field(default_factory=EnvConfig)
    ddpg: DDPGConfig = field(default_factory=DDPGConfig)
    train: TrainConfig = field(default_factory=TrainConfig)
    grid: GridConfig = field(default_factory=GridConfig)
    eval: EvalConfig = field(default_factory=EvalConfig)

    def to_dict(self) -> dict[str, dict[str, Any]]:
        return {
            name: {
                k: list(v) if isinstance(v, tuple) else v
                for k, v in dataclasses.asdict(getattr(self, name)).items()
            }
            for name in _TABLES
        }

    def hash(self) -> str:
        """Short stable hash of every value that shapes training (checkpoints record it):
        every table but ``[eval]``, so evaluating with other settings is the same run."""
        trained = {k: v for k, v in self.to_dict().items() if k != "eval"}
        blob = json.dumps(trained, sort_keys=True).encode()
        return hashlib.sha256(blob).hexdigest()[:12]


# The values a text key takes (the learners are jaxlc.learn.learners.LEARNERS; this module
# imports no other jaxlc module, and tests/test_ddpg.py checks that the two lists agree).
CHOICES: dict[str, tuple[str, ...]] = {
    "ddpg.learner": ("ddpg", "td3"),
    "env.longitudinal": ("idm", "policy"),
    "env.assist": ("none", "fitting", "fitting_hold"),
}

_TABLES: dict[str, type] = {
    "env": EnvConfig,
    "ddpg": DDPGConfig,
    "train": TrainConfig,
    "grid": GridConfig,
    "eval": EvalConfig,
}


def _allowed(meta: dict[str, Any]) -> str:
    lo, hi = meta.get("lo"), meta.get("hi")
    parts = []
    if lo is not None:
        parts.append(f"{'>' if meta.get('open_lo') else '>='} {lo:g}")
    if hi is not None:
        parts.append(f"<= {hi:g}")
    return " and ".join(parts)


def _check_scalar(key: str, value: Any, typ: type, meta: dict[str, Any]) -> Any:
    if key == "eval.traffic":  # overrides, each checked as a config value where it is applied
        if not (isinstance(value, str) and value.startswith("env.") and "=" in value):
            raise ConfigError(
                f"config key '{key}': each entry must be env.KEY=VALUE, got {value!r}"
            )
        return value
    if typ is str and key not in CHOICES:  # a name another layer resolves (a reward term)
        if not (isinstance(value, str) and value.isidentifier()):
            raise ConfigError(
                f"config key '{key}': must be a name (letters, digits, _), got {value!r}"
            )
        return value
    if typ is str:
        allowed = CHOICES[key]
        if value not in allowed:
            raise ConfigError(
                f"config key '{key}': must be one of {', '.join(map(repr, allowed))}, got {value!r}"
            )
        return value
    if typ is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"config key '{key}': must be true or false, got {value!r}")
        return value
    if typ is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"config key '{key}': must be an integer, got {value!r}")
    elif typ is float:
        if isinstance(value, bool) or not isinstance(value, int | float):
            raise ConfigError(f"config key '{key}': must be a number, got {value!r}")
        value = float(value)
        if not math.isfinite(value):
            raise ConfigError(f"config key '{key}': must be finite, got {value!r}")
    lo, hi = meta.get("lo"), meta.get("hi")
    bad_lo = lo is not None and (value <= lo if meta.get("open_lo") else value < lo)
    bad_hi = hi is not None and value > hi
    if bad_lo or bad_hi:
        raise ConfigError(f"config key '{key}': must be {_allowed(meta)}, got {value!r}")
    return value


def _check_field(key: str, value: Any, f: dataclasses.Field, hints: dict[str, Any]) -> Any:
    typ = hints[f.name]
    if isinstance(typ, types.UnionType):  # number | tuple: a constant or a [min, max] range
        if not isinstance(value, list | tuple):
            return _check_scalar(key, value, float, f.metadata)
        if len(value) != 2:
            raise ConfigError(
                f"config key '{key}': must be a number or a range [min, max], got {value!r}"
            )
        lo, hi = (_check_scalar(key, v, float, f.metadata) for v in value)
        if lo > hi:
            raise ConfigError(f"config key '{key}': a range [min, max] needs min <= max")
        return (lo, hi)
    if typing.get_origin(typ) is tuple:
        elem = typing.get_args(typ)[0]
        if not isinstance(value, list | tuple):
            raise ConfigError(
                f"config key '{key}': must be a list of {elem.__name__}, got {value!r}"
            )
        return tuple(_check_scalar(key, v, elem, f.metadata) for v in value)
    return _check_scalar(key, value, typ, f.metadata)


def _build(table: str, values: dict[str, Any]) -> Any:
    cls = _TABLES[table]
    fields = {f.name: f for f in dataclasses.fields(cls)}
    hints = typing.get_type_hints(cls)
    out = {}
    for key, value in values.items():
        if key not in fields:
            raise ConfigError(
                f"unknown config key '{table}.{key}'; allowed: {', '.join(sorted(fields))}"
            )
        out[key] = _check_field(f"{table}.{key}", value, fields[key], hints)
    return cls(**out)


def _cross_checks(cfg: Config) -> None:
    e, d, g = cfg.env, cfg.ddpg, cfg.grid
    if not e.reward_terms or len(set(e.reward_terms)) != len(e.reward_terms):
        raise ConfigError("config key 'env.reward_terms': must name one term or more, each once")
    if e.entry_speed_min > e.entry_speed_max:
        raise ConfigError("config key 'env.entry_speed_min': must be <= env.entry_speed_max")
    if e.desired_speed_min > e.desired_speed_max:
        raise ConfigError("config key 'env.desired_speed_min': must be <= env.desired_speed_max")
    if e.inflow_min > e.inflow_max:
        raise ConfigError("config key 'env.inflow_min': must be <= env.inflow_max")
    for lo, hi in (
        ("lane_change_time_min", "lane_change_time_max"),
        ("braking_decel_min", "braking_decel_max"),
        ("braking_time_min", "braking_time_max"),
    ):
        if getattr(e, lo) > getattr(e, hi):
            raise ConfigError(f"config key 'env.{lo}': must be <= env.{hi}")
    if e.braking_decel_max > e.idm_b_max:
        raise ConfigError(
            f"config key 'env.braking_decel_max': must be <= env.idm_b_max ({e.idm_b_max:g} "
            "m/s^2): a follower must be able to brake as hard as its leader"
        )
    if e.lane_width > e.border:
        raise ConfigError(
            f"config key 'env.lane_width': must be <= env.border ({e.border:g} m): the ego "
            f"starts one lane width from its target lane and is out of bounds beyond the border"
        )
    if e.gap_x_limit >= e.road_length:
        raise ConfigError("config key 'env.gap_x_limit': must be < env.road_length")
    if e.command_distance >= e.gap_x_limit:
        raise ConfigError("config key 'env.command_distance': must be < env.gap_x_limit")
    if not d.hidden:
        raise ConfigError("config key 'ddpg.hidden': must list at least one layer width")
    # without mirrored batches there is nothing to pair: mirror_pairs is then ignored, so
    # ddpg.mirror=false alone gives the unmirrored batches back
    if d.mirror and d.mirror_pairs and d.batch_size % 2:
        raise ConfigError(
            "config key 'ddpg.batch_size': reflection pairs (ddpg.mirror_pairs, the default) "
            f"need an even batch, got {d.batch_size}; or set ddpg.mirror_pairs = false"
        )
    for name in ("k", "memory"):
        if not getattr(g, name):
            raise ConfigError(f"config key 'grid.{name}': the grid needs at least one value")
    for m in g.memory:
        if m < d.batch_size:
            raise ConfigError(
                f"config key 'grid.memory': every size must be >= "
                f"ddpg.batch_size ({d.batch_size}), got {m}"
            )
    t = cfg.train
    if t.episodes % t.checkpoint_every:
        raise ConfigError("config key 'train.checkpoint_every': must divide train.episodes")
    # A chunk this short passes at most one checkpoint episode per model, so the one snapshot
    # slot per model suffices.
    n = MIN_EPISODE_STEPS
    if t.chunk_steps * t.envs_per_model > n * t.checkpoint_every:
        raise ConfigError(
            f"config key 'train.chunk_steps': must be <= {n} * train.checkpoint_every / "
            f"train.envs_per_model = {n * t.checkpoint_every // t.envs_per_model}, "
            f"got {t.chunk_steps}"
        )


def from_dict(data: dict[str, Any]) -> Config:
    """Build and validate a ``Config`` from nested tables (missing keys take defaults)."""
    for table, values in data.items():
        if table not in _TABLES:
            raise ConfigError(f"unknown config table '[{table}]'; allowed: {', '.join(_TABLES)}")
        if not isinstance(values, dict):
            raise ConfigError(f"config key '{table}': must be a table")
    data = _legacy(data)
    cfg = Config(**{t: _build(t, data.get(t, {})) for t in _TABLES})
    _cross_checks(cfg)
    return cfg


def _legacy(data: dict[str, Any]) -> dict[str, Any]:
    """Keys that runs were written with and that another key now holds: ``ddpg.td3`` (a bool,
    until ``ddpg.learner``) reads as ``learner = "td3"`` when true, as nothing when false."""
    d = data.get("ddpg", {})
    if "td3" not in d:
        return data
    d = dict(d)
    if _check_scalar("ddpg.td3", d.pop("td3"), bool, {}) and d.get("learner", "td3") == "td3":
        d["learner"] = "td3"
    elif "learner" not in d:
        d["learner"] = "ddpg"
    return {**data, "ddpg": d}


def parse_override(text: str) -> tuple[str, str, Any]:
    """``"ddpg.actor_lr=3e-4"`` -> ``("ddpg", "actor_lr", 3e-4)``; values use TOML syntax."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise ConfigError(
            f"override '{text}': must look like table.key=value, e.g. train.episodes=200"
        )
    lhs, raw = text.split("=", 1)
    table, key = lhs.strip().split(".", 1)
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()  # a bare word: let type validation name the problem
    return table, key, value


def load(
    path: str | Path | None = None,
    overrides: typing.Sequence[str] = (),
    missing: typing.Mapping[str, typing.Mapping[str, Any]] | None = None,
) -> Config:
    """Load ``path`` (default ``configs/default.toml``), apply overrides, validate.

    ``missing``: values for keys the file does not spell, in place of the defaults (a run's
    resolved config spells every key, so there a missing key dates the run)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    data: dict[str, Any] = {}
    if path.exists() or path != DEFAULT_CONFIG:
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise ConfigError(f"config file '{path}' does not exist") from None
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file '{path}' is not valid TOML: {err}") from None
    for table, keys in (missing or {}).items():
        for key, value in keys.items():
            _table(data, table).setdefault(key, value)
    for text in overrides:
        table, key, value = parse_override(text)
        _table(data, table)[key] = value
    return from_dict(data)


def _table(data: dict[str, Any], table: str) -> dict[str, Any]:
    """``data[table]``, made if absent; a non-table there is refused."""
    data.setdefault(table, {})
    if not isinstance(data[table], dict):
        raise ConfigError(f"config key '{table}': must be a table")
    return data[table]


def to_toml(cfg: Config) -> str:
    """Serialise a config as TOML (the run directory keeps the resolved config)."""

    def fmt(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, list):
            return "[" + ", ".join(fmt(x) for x in v) + "]"
        if isinstance(v, str):
            return json.dumps(v)  # a TOML basic string
        return repr(v)

    lines = []
    for table, values in cfg.to_dict().items():
        lines.append(f"[{table}]")
        lines += [f"{k} = {fmt(v)}" for k, v in values.items()]
        lines.append("")
    return "\n".join(lines)
