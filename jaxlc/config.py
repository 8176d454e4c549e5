"""Typed, frozen configuration loaded from TOML and validated once, at the edge.

A config file has four tables, ``[env]``, ``[ddpg]``, ``[train]`` and ``[grid]``; every field
below is a key of its table. ``configs/default.toml`` holds the dataclasses' defaults, the
built-in default of ``python -m jaxlc.sweep``; ``configs/paper.toml`` the paper's method as
written. Overrides are ``table.key=value`` strings (TOML syntax for the value).

Any problem (unknown table or key, wrong type, value out of range) raises ``ConfigError`` with
one line naming the key and what is allowed; nothing is run with a bad config. The ``[env]``
keys are declared once, in ``EnvParams`` (``jaxlc/sim/params.py``): ``EnvConfig`` is made from
that declaration. A run's config written by an older jaxlc reads through ``migrate``.

This module stays at the bottom of the package, below every layer: ``jaxlc.sim``, ``learn``,
``study`` and ``evaluation`` may all import it, and it imports no other jaxlc module but
``jaxlc.sim.params``, the env's declaration (``tests/test_layout.py`` checks both).
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

from jaxlc.sim.params import ConfigError, EnvParams, settings, value_range

CONFIG_DIR = Path(__file__).resolve().parent.parent / "configs"
PAPER_CONFIG = CONFIG_DIR / "paper.toml"  # the paper's method as written
DEFAULT_CONFIG = CONFIG_DIR / "default.toml"  # the built-in default: the dataclasses' values
# Fewest env-steps one episode can take: the ego must drive command_distance (80 m) from the
# entrance at no more than its entry speed plus IDM acceleration; 50 steps (5 s) is below that.
MIN_EPISODE_STEPS = 50


def _f(
    default: Any,
    lo: float | None = None,
    hi: float | None = None,
    *,
    open_lo: bool = False,
    doc: str = "",
    choices: tuple[str, ...] = (),
) -> Any:
    """A dataclass field with bounds: ``lo <= v <= hi`` (``lo < v`` when ``open_lo``), or one
    of ``choices`` (a text key)."""
    meta = {"lo": lo, "hi": hi, "open_lo": open_lo, "doc": doc, "choices": choices}
    if isinstance(default, list | tuple):
        return field(default_factory=lambda: tuple(default), metadata=meta)
    return field(default=default, metadata=meta)


def _env_table() -> type:
    """``[env]``: ``EnvParams``' settings (``jaxlc/sim/params.py``, one declaration each) as
    keys in the units a file is written in, in their order, with their defaults and bounds."""
    hints = typing.get_type_hints(EnvParams)
    keys = [
        (m["key"] or f.name, m["toml"] or hints[f.name], field(default=m["default"], metadata=m))
        for f in settings()
        for m in [f.metadata]
    ]
    doc = "The [env] table: EnvParams' settings in a config file's units (jaxlc/sim/params.py)."
    return dataclasses.make_dataclass(
        "EnvConfig", keys, frozen=True, namespace={"__doc__": doc, "__module__": __name__}
    )


EnvConfig = _env_table()


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
    # the learners are jaxlc.learn.learners.LEARNERS (tests/test_ddpg.py checks they agree)
    learner: str = _f(
        "ddpg", doc="the learner: 'ddpg' (the paper's) or 'td3'", choices=("ddpg", "td3")
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
    held_aware: bool = _f(
        False,
        doc="with k > 1: the target's next action is the held one where s' does not refresh "
        "it, and the actor learns on the states that do (the paper: false)",
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
    suite: str = _f(
        "",
        doc="the held-out suite of --suite: a file of named settings, or its name in configs/ "
        "('suite': configs/suite.toml); '' for configs/suite.toml",
    )
    choose_episodes: tuple[int, ...] = _f(
        [],
        1,
        doc="--choose: the episodes whose checkpoints each model's final is weighed against on "
        "the suite's settings; the fewest failures is the model's policy ([]: the final one)",
    )
    choose_lane_changes: int = _f(200, 1, doc="--choose: lane changes per checkpoint and setting")
    choose_seed: int = _f(
        1, 0, 2**31 - 1, doc="--choose: seed of its lane changes, never eval.heldout_seed"
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


_TABLES: dict[str, type] = {
    "env": EnvConfig,
    "ddpg": DDPGConfig,
    "train": TrainConfig,
    "grid": GridConfig,
    "eval": EvalConfig,
}
# The values a text key takes, as its field declares them.
CHOICES: dict[str, tuple[str, ...]] = {
    f"{table}.{f.name}": f.metadata["choices"]
    for table, cls in _TABLES.items()
    for f in dataclasses.fields(cls)
    if f.metadata.get("choices")
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
    if key == "eval.suite":  # a file, read where it is used (jaxlc.evaluation.suite.load)
        if not isinstance(value, str):
            raise ConfigError(f"config key '{key}': must be a file name, got {value!r}")
        return value
    allowed = meta.get("choices")
    if typ is str and not allowed:  # a name another layer resolves (a reward term)
        if not (isinstance(value, str) and value.isidentifier()):
            raise ConfigError(
                f"config key '{key}': must be a name (letters, digits, _), got {value!r}"
            )
        return value
    if typ is str:
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
    e = cfg.env
    if not e.reward_terms or len(set(e.reward_terms)) != len(e.reward_terms):
        raise ConfigError("config key 'env.reward_terms': must name one term or more, each once")
    for lo, hi in (
        ("entry_speed_min", "entry_speed_max"),
        ("desired_speed_min", "desired_speed_max"),
        ("inflow_min", "inflow_max"),
    ):  # each may be a range drawn per episode: its ends no higher than the other's
        if any(a > b for a, b in zip(*(value_range(getattr(e, k)) for k in (lo, hi)), strict=True)):
            raise ConfigError(f"config key 'env.{lo}': must be <= env.{hi} (at each end)")
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
    if cfg.eval.choose_episodes and cfg.eval.choose_seed == cfg.eval.heldout_seed:
        raise ConfigError(
            "config key 'eval.choose_seed': must differ from eval.heldout_seed (a checkpoint "
            "chosen on the lane changes it is judged on would flatter it)"
        )
    speeds = e.operating_speed
    if len(speeds) not in (0, 2) or list(speeds) != sorted(speeds) or any(v < 0 for v in speeds):
        raise ConfigError(
            "config key 'env.operating_speed': must be [] (off) or [min, max] km/h, 0 <= min <= max"
        )
    if e.manoeuvre_distance and e.manoeuvre_time_max < e.manoeuvre_time_limit:
        raise ConfigError(
            "config key 'env.manoeuvre_time_max': must be >= env.manoeuvre_time_limit "
            "with env.manoeuvre_distance on"
        )
    if value_range(e.lane_width)[1] > e.border:
        raise ConfigError(
            f"config key 'env.lane_width': must be <= env.border ({e.border:g} m): the ego "
            f"starts one lane width from its target lane and is out of bounds beyond the border"
        )
    if e.gap_x_limit >= e.road_length:
        raise ConfigError("config key 'env.gap_x_limit': must be < env.road_length")
    if e.command_distance >= e.gap_x_limit:
        raise ConfigError("config key 'env.command_distance': must be < env.gap_x_limit")
    _learner_checks(cfg)
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


def _learner_checks(cfg: Config) -> None:
    """The ``[ddpg]`` values against each other and against the grid's memories."""
    d, g = cfg.ddpg, cfg.grid
    if not d.hidden:
        raise ConfigError("config key 'ddpg.hidden': must list at least one layer width")
    # without mirrored batches there is nothing to pair: mirror_pairs is then ignored, so
    # ddpg.mirror=false alone gives the unmirrored batches back
    if d.mirror and d.mirror_pairs and d.batch_size % 2:
        raise ConfigError(
            "config key 'ddpg.batch_size': reflection pairs (ddpg.mirror_pairs, the default) "
            f"need an even batch, got {d.batch_size}; or set ddpg.mirror_pairs = false"
        )
    if d.held_aware and (d.learner != "ddpg" or cfg.env.longitudinal == "policy"):
        raise ConfigError(
            "config key 'ddpg.held_aware': needs ddpg.learner = 'ddpg' and one action "
            "(env.longitudinal other than 'policy')"
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


def from_dict(data: dict[str, Any], *, resolved: bool = False) -> Config:
    """Build and validate a ``Config`` from nested tables (missing keys take defaults; a
    ``resolved`` run's config reads through ``migrate`` as one)."""
    for table, values in data.items():
        if table not in _TABLES:
            raise ConfigError(f"unknown config table '[{table}]'; allowed: {', '.join(_TABLES)}")
        if not isinstance(values, dict):
            raise ConfigError(f"config key '{table}': must be a table")
    data = migrate(data, resolved=resolved)
    cfg = Config(**{t: _build(t, data.get(t, {})) for t in _TABLES})
    _cross_checks(cfg)
    return cfg


# How jaxlc's configs changed, oldest first: each version, the keys it added with the value that
# reproduces how a run written before behaved, and the keys it renamed (old -> (new, value of the
# old -> value of the new)). A run's resolved config (``to_toml``) spells every key it had, so
# the keys it lacks date it; a file a user writes takes today's defaults for the keys it omits.
VERSIONS: tuple[tuple[str, dict[str, Any], dict[str, tuple[str, Any]]], ...] = (
    # time-to-collision test of a gap; the odd (symmetric) actor
    ("2026-11-23", {"env.gap_min_ttc": 0.0, "ddpg.symmetric_actor": False}, {}),
    # ddpg.learner ('ddpg' | 'td3') replaces the bool ddpg.td3
    (
        "2026-11-25",
        {},
        {"ddpg.td3": ("ddpg.learner", lambda v: "td3" if _bool("ddpg.td3", v) else "ddpg")},
    ),
    # reflection pairs; before them, rows were reflected at random
    ("2026-11-26", {"ddpg.mirror_pairs": False}, {}),
)


def _bool(key: str, value: Any) -> bool:
    return _check_scalar(key, value, bool, {})


def migrate(data: dict[str, Any], *, resolved: bool = False) -> dict[str, Any]:
    """``data`` (a config's tables as read) in today's keys, version by version (``VERSIONS``):
    a renamed key reads as its successor (an explicit successor wins); with ``resolved`` (a
    run's config), a key added since it was written takes the value the run ran with."""
    data = {table: dict(values) for table, values in data.items()}
    for _, added, renamed in VERSIONS:
        for old, (new, convert) in renamed.items():
            table, key = old.split(".")
            if key in data.get(table, {}):
                new_table, new_key = new.split(".")
                data.setdefault(new_table, {}).setdefault(new_key, convert(data[table].pop(key)))
        for name, value in added.items() if resolved else ():
            table, key = name.split(".")
            data.setdefault(table, {}).setdefault(key, value)
    return data


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
    *,
    resolved: bool = False,
) -> Config:
    """Load ``path`` (default ``configs/default.toml``), apply overrides, validate.

    ``resolved``: ``path`` is a run's resolved config, which spells every key its version had
    (``migrate``)."""
    path = Path(path) if path is not None else DEFAULT_CONFIG
    data: dict[str, Any] = {}
    if path.exists() or path != DEFAULT_CONFIG:
        try:
            data = tomllib.loads(path.read_text())
        except FileNotFoundError:
            raise ConfigError(f"config file '{path}' does not exist") from None
        except tomllib.TOMLDecodeError as err:
            raise ConfigError(f"config file '{path}' is not valid TOML: {err}") from None
    for text in overrides:
        table, key, value = parse_override(text)
        _table(data, table)[key] = value
    return from_dict(data, resolved=resolved)


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
