"""What the evaluation measures of each lane change, each declared once.

A ``Measure`` is a name, a reducer over the manoeuvre's RL steps (``sum``, ``max``, ``min``,
``last``, ``first``) and a function of one ``Step``, the way reward terms are
(``jaxlc.sim.reward.register``). The rollout (``jaxlc.evaluation.cases``) folds every
measure over the steps of every policy and case into an ``Outcome``, whose columns reach
``eval/cases.npz``, ``heldout_cases.npz``, the result rows and, for a measure with a
``heldout`` summary, ``heldout.csv`` and the held-out tables of ``report.md``. A measure of
your own is ``register``-ed before the evaluation runs; nothing else changes:

    def speed_drop(s: measures.Step, p) -> jax.Array:
        return s.state.ego.v0 - s.state.ego.v

    measures.register(measures.Measure("max_speed_drop", "max", speed_drop, heldout="mean"))

Reducers, each over the steps where the case is live (still in its manoeuvre): ``sum``,
``max`` and ``min`` as named; ``last`` keeps the value at the manoeuvre's last step; ``first``
keeps the first value other than ``fill`` (``fill`` means "not yet"). ``from_start``: the
manoeuvre's start state counts as a step (step 0; ``Step.reason`` the case's, its
proposal's records those of its approach); else the value starts at
``fill``, with ``shape``'s axes past ``(policies, cases)``. ``at_end``: the function is read
once, on the state the case froze in (its last step's, so the same as ``last``), where it
costs one evaluation, not one per step; it may read ``state``, ``reason``, ``steps`` and
``performed`` only.

Safety and comfort (``jaxlc.evaluation.safety``): headway and TTC only where they count
(``safety.counted``), else inf; the jerks over a 0.5 s moving average; UN R79's lane change
manoeuvre from the RL step at which the body first overlaps the target lane to the first
after it with the body wholly past the origin lane (-1 until then).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.evaluation import safety
from jaxlc.sim.collision import clearance, overlaps
from jaxlc.sim.reward import COLLISION, OUT_OF_BOUNDS, step_limit
from jaxlc.sim.reward import names as reward_names
from jaxlc.sim.road import ego_yaw_rate, road_curvature

REDUCERS = ("sum", "max", "min", "last", "first")
# The held-out row's summaries of a measure (jaxlc.evaluation.heldout.model_row), over the
# lane changes: the mean over the successful ones, the 5th percentile over all (the low tail
# of a safety measure), the total.
SUMMARIES = ("mean", "p5", "sum")


@flax.struct.dataclass
class Step:
    """What a measure reads at one RL step; each leaf ``(policies, cases, ...)``."""

    state: Any  # EnvState after the step
    reason: Array  # int32 end reason of the step (0: goes on)
    steps: Array  # int32 RL steps of the manoeuvre so far (info["episode_steps"])
    reward: Array
    info: dict[str, Array]  # the env's info of the step (reward terms, offset, hazards)
    side: Array  # float32 +1 toward higher y (left), -1 right
    performed: Array  # bool: the case reached the RL phase
    lat_jerk: Array  # windowed lateral jerk, m/s^3 (safety.observe)
    long_jerk: Array  # windowed longitudinal jerk, m/s^3
    counted: Array  # (..., 3) bool: whose headway and TTC count (safety.VEHICLES)
    tilt: Array | float = 0.0  # a proposal's records of the step, (..., stats)


class Measure(NamedTuple):
    """One column of the outcome: ``fn(step, params)`` folded by ``reduce``."""

    name: str
    reduce: str  # one of REDUCERS
    fn: Callable[[Step, Any], Array]
    fill: float | int = 0  # the value before any step; for "first", "not yet"
    dtype: Any = jnp.float32
    from_start: bool = False
    at_end: bool = False
    heldout: str | None = None  # a summary of SUMMARIES: a column of heldout.csv
    shape: tuple[int, ...] = ()  # the value's axes past (policies, cases), unless from_start


def _toward(s: Step, p) -> Array:
    """Signed offset to the target centre line, toward the target side, m."""
    return s.info["offset"] * s.side


def _yaw(s: Step, p) -> Array:
    """The yaw rate the success test reads: relative to the lane's (omega when straight)."""
    return ego_yaw_rate(s.state.ego, jnp.broadcast_to(road_curvature(s.state, p), s.side.shape), p)


def _conflict(i: int) -> Callable[[Step, Any], Array]:
    """TTC (``i = 0``) or time headway (1) to each of ``safety.VEHICLES`` where it counts."""
    return lambda s, p: jnp.where(s.counted, safety.conflicts(s.state, p)[i], jnp.inf)


def _lcm(s: Step, p, end: bool) -> Array:
    """The step where the body is over the line (``end``: and wholly out of the origin lane)."""
    entered = s.counted[..., 0]  # counted: (lead, lag, own); the lead's is "entered"
    at = entered & safety.crossed(s.state, p) if end else entered
    return jnp.where(at, s.steps, -1)


def _hit(s: Step) -> Array:
    """Performed lane changes that ended in a collision."""
    return s.performed & (s.reason == COLLISION)


def _overlap(s: Step, p) -> Array:
    """``(policies, cases, lanes, slots)`` the vehicles the ego's box overlaps."""
    kappa = jnp.broadcast_to(road_curvature(s.state, p), s.reason.shape)
    both = jax.vmap(jax.vmap(overlaps, (0, 0, None, 0)), (0, 0, None, 0))
    return both(s.state.traffic, s.state.ego, p, kappa)


def _partner(s: Step, p) -> Array:
    return jnp.where(_hit(s), safety.partner(_overlap(s, p), s.state.traffic, s.state.ego, p), 0)


def _hazard(s: Step, p) -> Array:
    return jnp.where(_hit(s), safety.hazard(_overlap(s, p), s.state.traffic), 0)


def gap_margin(s: Step, p) -> Array:
    """Metres between the ego's body and the nearest other body (``collision.clearance``);
    exactly 0 on the step that ends in a collision."""
    kappa = jnp.broadcast_to(road_curvature(s.state, p), s.reason.shape)
    each = clearance
    for _ in range(s.reason.ndim):  # any batch axes: (policies, cases) or none (ams)
        each = jax.vmap(each, (0, 0, None, 0))
    gap = each(s.state.traffic, s.state.ego, p, kappa).min(axis=(-2, -1))
    return jnp.where(s.reason == COLLISION, 0.0, gap)


def time_margin(s: Step, p) -> Array:
    """Seconds left before the manoeuvre's limit (``reward.step_limit``): 0 on a timeout."""
    return (step_limit(p) - s.steps) * p.dt


def border_margin(s: Step, p) -> Array:
    """Metres left to the border past the target lane (``|offset| > border`` is out of
    bounds; every manoeuvre starts on the origin side's, so that side reads 0 from the
    command on and says nothing): exactly 0 on the step that ends out of bounds."""
    return jnp.where(s.reason == OUT_OF_BOUNDS, 0.0, jnp.maximum(p.border - _toward(s, p), 0.0))


# The margins of "How close to failure" (SPEC): per failure kind, how close the manoeuvre
# came, 0 exactly where it ended in that failure (jaxlc.evaluation.ams splits on them).
MARGINS = {"collision": "margin_gap", "timeout": "margin_time", "out_of_bounds": "margin_border"}
I32 = jnp.int32
# The outcome's columns in their order (the reward terms' follow "ret": ``of``). Each
# ``(policies, cases)`` unless its function's value has more axes; dynamics are over the RL
# steps, comfort and safety include the start state where ``from_start``.
BUILTIN: tuple[Measure, ...] = (
    # int32 outcome index (results.OUTCOMES): the case's before its RL phase
    Measure("reason", "last", lambda s, p: s.reason, 0, I32, from_start=True),
    Measure("performed", "last", lambda s, p: s.performed, False, bool, from_start=True),
    Measure("ret", "sum", lambda s, p: s.reward),  # total return
    Measure("steps", "last", lambda s, p: s.steps, 0, I32),  # RL steps of the manoeuvre
    Measure("peak_lat_acc", "max", lambda s, p: jnp.abs(safety.lateral_acc(s.state))),  # m/s^2
    Measure("peak_yaw_rate", "max", lambda s, p: jnp.abs(_yaw(s, p))),  # rad/s
    Measure("overshoot", "max", _toward),  # m past the target centre line (0 if none)
    # The ego at the manoeuvre's last step (NaN without one), so a timeout's cause shows:
    # short of the lane (offset < 0), swinging (large omega) or just outside the success box.
    Measure("final_offset", "last", _toward, jnp.nan),  # m toward the target side
    Measure("final_psi", "last", lambda s, p: s.state.ego.psi, jnp.nan),  # rad
    Measure("final_omega", "last", _yaw, jnp.nan),  # rad/s relative to the lane's
    Measure("peak_lat_jerk", "max", lambda s, p: jnp.abs(s.lat_jerk)),  # m/s^3
    Measure("peak_long_acc", "max", lambda s, p: jnp.abs(s.state.ego.accel)),  # m/s^2
    Measure("peak_long_jerk", "max", lambda s, p: jnp.abs(s.long_jerk)),  # m/s^3
    Measure("lcm_start", "first", lambda s, p: _lcm(s, p, False), -1, I32, from_start=True),
    Measure("lcm_end", "first", lambda s, p: _lcm(s, p, True), -1, I32, from_start=True),
    Measure("min_ttc", "min", _conflict(0), jnp.inf, from_start=True),  # (..., 3) s
    Measure("min_thw", "min", _conflict(1), jnp.inf, from_start=True),  # (..., 3) s
    # The collision, if any: the vehicle hit (safety.PARTNERS) and the ego's speed.
    Measure("partner", "last", _partner, 0, I32, at_end=True),
    Measure(
        "hit_speed",
        "last",
        lambda s, p: jnp.where(_hit(s), s.state.ego.v, jnp.nan),
        jnp.nan,
        at_end=True,
    ),  # fmt: skip
    # The traffic's hazards (env.mobil, env.braking; 0 in the paper's traffic): cut-ins met,
    # braking events near the ego, what the vehicle hit was doing (safety.HAZARDS).
    Measure("cut_ins", "sum", lambda s, p: s.info.get("cut_in", False), 0, I32),
    Measure("brakes_near", "sum", lambda s, p: s.info.get("brake_near", 0), 0, I32),
    Measure("hit_hazard", "last", _hazard, 0, I32, at_end=True),
    # A proposal's records: log ratios and statistics (jaxlc.validate), the approach's included.
    Measure("tilt", "sum", lambda s, p: s.tilt, from_start=True),  # (..., stats)
    # How close each lane change came to each failure (MARGINS), over its RL steps.
    Measure("margin_gap", "min", gap_margin, jnp.inf),  # m, least clearance
    Measure("margin_time", "last", time_margin, jnp.nan),  # s left at the end
    Measure("margin_border", "min", border_margin, jnp.inf),  # m, least left to the border
)
_REGISTRY: dict[str, Measure] = {}


def register(m: Measure) -> Measure:
    """Add ``m`` to every evaluation from now on (a name taken by another is refused)."""
    if m.reduce not in REDUCERS or m.heldout not in (None, *SUMMARIES):
        raise ValueError(f"measure {m.name!r}: reducer one of {REDUCERS}, heldout of {SUMMARIES}")
    if m.at_end and m.reduce != "last":
        raise ValueError(f"measure {m.name!r}: only a 'last' measure is read at the end")
    known = _REGISTRY.get(m.name)
    if any(b.name == m.name for b in BUILTIN) or (known is not None and known != m):
        raise ValueError(f"measure {m.name!r} is registered already: choose another name")
    _REGISTRY[m.name] = m
    return m


def unregister(name: str) -> None:
    """Take a registered measure out again (tests)."""
    _REGISTRY.pop(name, None)


def registered() -> tuple[Measure, ...]:
    """The measures of your own, in the order registered."""
    return tuple(_REGISTRY.values())


def of(p) -> tuple[Measure, ...]:
    """Every measure of an evaluation under ``p`` (EnvParams), in column order: the built-in
    ones with each reward term's sum after ``ret``, then those registered."""
    at = [b.name for b in BUILTIN].index("ret") + 1
    terms = tuple(Measure(n, "sum", lambda s, p, n=n: s.info[n]) for n in reward_names(p))
    return BUILTIN[:at] + terms + BUILTIN[at:] + registered()


@flax.struct.dataclass
class Outcome:
    """Each measure's value per policy and case ``(policies, cases, ...)``, in ``names``'
    order (a pytree's dict would come back with its keys sorted)."""

    values: tuple[Array, ...]
    names: tuple[str, ...] = flax.struct.field(pytree_node=False, default=())

    def __getitem__(self, name: str) -> Array:
        return self.values[self.names.index(name)]

    def columns(self) -> dict[str, Array]:
        return dict(zip(self.names, self.values, strict=True))


def _expand(live: Array, like: Array) -> Array:
    """``live (policies, cases)`` with an axis of 1 for each of ``like``'s further axes."""
    return live.reshape(live.shape + (1,) * (jnp.ndim(like) - live.ndim))


def start(ms: tuple[Measure, ...], s: Step, p) -> Outcome:
    """Each measure before the first RL step (``s``: the manoeuvre's start, step 0, its
    leaves ``(policies, cases, ...)``): its function there where ``from_start``, else ``fill``
    in the shape and dtype of its value."""
    values = []
    for m in ms:
        if m.from_start:
            v = jnp.asarray(m.fn(s, p), m.dtype)
            values.append(jnp.broadcast_to(v, s.reason.shape + v.shape[s.reason.ndim :]))
        else:
            values.append(jnp.full(s.reason.shape + m.shape, m.fill, m.dtype))
    return Outcome(tuple(values), tuple(m.name for m in ms))


def fold(ms: tuple[Measure, ...], out: Outcome, s: Step, live: Array, p) -> Outcome:
    """``out`` with one RL step folded in; only ``live`` ``(policies, cases)`` entries change.
    ``at_end`` measures wait for ``finish``."""
    values = []
    for m, acc in zip(ms, out.values, strict=True):
        if m.at_end:
            values.append(acc)
            continue
        v, on = m.fn(s, p), _expand(live, acc)
        if m.reduce == "sum":
            acc = acc + jnp.where(on, v, 0).astype(acc.dtype)
        elif m.reduce == "max":
            acc = jnp.maximum(acc, jnp.where(on, v, acc))
        elif m.reduce == "min":
            acc = jnp.minimum(acc, jnp.where(on, v, acc))
        elif m.reduce == "last":
            acc = jnp.where(on, v, acc)
        else:  # first: the first value other than fill
            acc = jnp.where(on & (acc == m.fill) & (v != m.fill), v, acc)
        values.append(jnp.asarray(acc, m.dtype))
    return out.replace(values=tuple(values))


def finish(ms: tuple[Measure, ...], out: Outcome, end: Step, p) -> Outcome:
    """``out`` with each ``at_end`` measure read on ``end``: every case's frozen last state,
    its reason and steps those folded into ``out``."""
    values = tuple(
        jnp.asarray(m.fn(end, p), m.dtype) if m.at_end else v
        for m, v in zip(ms, out.values, strict=True)
    )
    return out.replace(values=values)
