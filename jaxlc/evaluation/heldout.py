"""What the held-out evaluation concludes (docs/usage.md, "Held-out lane changes, safety and
comfort"): per model its rates with 95% Clopper-Pearson intervals and the one-sided bound on
its failures, the norms per lane change, every collision attributed, cells over seeds and
lane changes, and claim (d) as a bound. Pure numpy/scipy.

A cell's mean success: with >= ``MIN_BOOT_SEEDS`` seeds a two-level bootstrap (seeds, then
each seed's lane changes) at ``stats.expanded_level``; with fewer, the range of its seeds'
Clopper-Pearson intervals (``interval`` says which). Its pooled one-sided failure bound is
conservative for the mean of its models' rates (Hoeffding 1956).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import fields as dataclass_fields

import numpy as np
import scipy.stats

from jaxlc import config
from jaxlc.evaluation import measures
from jaxlc.evaluation.cases import CaseInfo
from jaxlc.evaluation.results import (
    OUTCOMES,
    SCRIPTED,
    Claim,
    Collision,
    HeldoutCell,
    HeldoutRow,
    Policy,
    heldout_fields,
    mean_or_nan,
)
from jaxlc.evaluation.safety import HAZARDS, NORMS, PARTNERS, VEHICLES
from jaxlc.evaluation.stats import CONFIDENCE, RESAMPLES, expanded_level
from jaxlc.paper.claims import CLAIM_D, SOLVED
from jaxlc.paper.grid import BEST_TAG, is_best

MIN_BOOT_SEEDS = 5
BOUNDS = {name: bound for name, bound, *_ in NORMS}
# Measured beside the norms (no norm of their own here): comfort along the road.
LONGITUDINAL = ("peak_long_acc", "peak_long_jerk")
# Means over the successful lane changes.
MEANS = ("duration_s", "lcm_s", "lcm_start_s", "peak_lat_acc", "peak_lat_jerk") + LONGITUDINAL
ENDS = ("success", "out_of_bounds", "collision", "timeout", "unfinished")
NORM_KEYS = tuple(f"norm_{name}" for name, *_ in NORMS) + ("norm_all",)
# The traffic's hazards met (env.mobil, env.braking): cut-ins, lane changes that met one,
# braking events of the vehicles around the ego; 0 in the paper's traffic.
HAZARD_KEYS = ("cut_ins", "met_cut_in", "brakes_near", "met_braking")
# How close the lane changes came to each failure (measures.MARGINS): 5th pct. and median.
MARGIN_KEYS = tuple(f"{m}_{q}" for m in measures.MARGINS.values() for q in ("p5", "p50"))


def fields() -> tuple[str, ...]:
    """``heldout.csv``'s columns: ``HeldoutRow``'s, then each measure registered with a
    held-out summary (``measures.register``), by its name."""
    return heldout_fields([*MARGIN_KEYS, *(m.name for m in measures.registered() if m.heldout)])


def _summary(m: measures.Measure, values: np.ndarray, ok: np.ndarray) -> float:
    """A registered measure's held-out column from its values on the lane changes
    ``(lane changes,)`` (``ok``: the successful ones)."""
    if m.heldout == "mean":
        return mean_or_nan(values[ok])
    return _p5(values) if m.heldout == "p5" else float(values.sum())


COLLISION_FIELDS = tuple(f.name for f in dataclass_fields(Collision))


def clopper_pearson(k: int, n: int, confidence: float = CONFIDENCE) -> tuple[float, float]:
    """Two-sided exact binomial interval of a rate from ``k`` of ``n``; NaN for n = 0."""
    if n == 0:
        return math.nan, math.nan
    a = 1.0 - confidence
    lo = 0.0 if k == 0 else float(scipy.stats.beta.ppf(a / 2, k, n - k + 1))
    hi = 1.0 if k == n else float(scipy.stats.beta.ppf(1 - a / 2, k + 1, n - k))
    return lo, hi


def upper_bound(k: int, n: int, confidence: float = CONFIDENCE) -> float:
    """One-sided exact upper bound on a rate from ``k`` of ``n`` (0 of 1000: 0.30%)."""
    if n == 0:
        return math.nan
    return 1.0 if k == n else float(scipy.stats.beta.ppf(confidence, k + 1, n - k))


def lane_change_measures(out: dict[str, np.ndarray], p: int, dt: float) -> dict[str, np.ndarray]:
    """Policy ``p``'s measures per case ``(cases,)``: the NORMS' measures (a failed lane change
    has no duration: inf) and whether each norm, and all of them with success, hold.

    ``duration_s`` is the whole RL phase, ``lcm_s`` UN R79's lane change manoeuvre (the body
    from first over the line to wholly across it) and ``lcm_start_s`` when it began after the
    command (``jaxlc.evaluation.safety``)."""
    ok = out["reason"][p] == OUTCOMES.index("success")
    start, end = out["lcm_start"][p], out["lcm_end"][p]
    m = {
        "duration_s": np.where(ok, out["steps"][p] * dt, np.inf),
        "lcm_s": np.where(ok & (start >= 0) & (end >= 0), (end - start) * dt, np.inf),
        "lcm_start_s": np.where(start >= 0, start * dt, np.inf),
        "peak_lat_acc": out["peak_lat_acc"][p],
        "peak_lat_jerk": out["peak_lat_jerk"][p],
        "min_ttc_s": out["min_ttc"][p].min(axis=-1),
        "min_thw_s": out["min_thw"][p].min(axis=-1),
        **{k: out[k][p] for k in LONGITUDINAL},
    }
    inside = {
        f"norm_{name}": (m[name] < bound) if below else (m[name] >= bound)
        for name, bound, below, _ in NORMS
    }
    inside["norm_all"] = ok & np.all(list(inside.values()), axis=0)
    return {**m, **inside}


def _p5(x: np.ndarray, q: int = 5) -> float:
    """The ``q``th percentile (an observed value), NaN of none."""
    return float(np.percentile(x, q, method="lower")) if x.size else math.nan


def _margins(out: dict[str, np.ndarray], p: int, perf: np.ndarray) -> dict[str, float]:
    """``MARGIN_KEYS`` of policy ``p``'s lane changes (outcomes without margins: none)."""
    names = [m for m in measures.MARGINS.values() if m in out]
    return {f"{m}_p{q}": _p5(out[m][p][perf], q) for m in names for q in (5, 50)}


def model_row(
    out: dict[str, np.ndarray],
    info: CaseInfo,
    p: int,
    dt: float,
    policy: Policy = SCRIPTED,
) -> HeldoutRow:
    """Policy ``p``'s held-out row, ``policy`` its identity."""
    perf = info.performed
    reason = out["reason"][p][perf]
    n = int(perf.sum())
    counts = {e: int((reason == OUTCOMES.index(e)).sum()) for e in ENDS}
    ok = reason == OUTCOMES.index("success")
    m = {k: v[perf] for k, v in lane_change_measures(out, p, dt).items()}
    wins, hits = counts["success"], counts["collision"]
    fails = n - wins
    own = [me for me in measures.registered() if me.heldout]  # measures of your own
    crit = {}  # the share of lane changes critical, per vehicle
    for name in ("ttc", "thw"):
        bound = BOUNDS[f"min_{name}_s"]
        for i, v in enumerate(VEHICLES):
            crit[f"{name}_crit_{v}"] = mean_or_nan(out[f"min_{name}"][p][perf][:, i] < bound)
    s_lo, s_hi = clopper_pearson(wins, n)
    c_lo, c_hi = clopper_pearson(hits, n)
    cuts, brakes = out["cut_ins"][p][perf], out["brakes_near"][p][perf]
    return HeldoutRow(
        **policy.as_dict(),
        lane_changes=n,
        **counts,
        success_rate=wins / n if n else math.nan,
        success_lo=s_lo,
        success_hi=s_hi,
        failure_bound=upper_bound(fails, n),
        collision_rate=hits / n if n else math.nan,
        collision_lo=c_lo,
        collision_hi=c_hi,
        **{k: mean_or_nan(m[k][ok]) for k in MEANS},
        # The low tail is what safety is about: 5th percentiles over the lane changes.
        **{k: _p5(m[k]) for k in ("min_ttc_s", "min_thw_s")},
        **{k: mean_or_nan(m[k]) for k in NORM_KEYS},
        **crit,
        cut_ins=int(cuts.sum()),
        met_cut_in=int((cuts > 0).sum()),
        brakes_near=int(brakes.sum()),
        met_braking=int((brakes > 0).sum()),
        measures={
            **_margins(out, p, perf),
            **{me.name: _summary(me, out[me.name][p][perf], ok) for me in own},
        },
    )


def collisions(
    out: dict[str, np.ndarray], info: CaseInfo, metas: list[Policy], dt: float
) -> list[Collision]:
    """One record per collision: the vehicle hit, the ego's speed and time into the
    manoeuvre, the gaps and lag speed at acceptance, whether the lag yields."""
    rows = []
    code = OUTCOMES.index("collision")
    for p, meta in enumerate(metas):
        for c in np.nonzero(info.performed & (out["reason"][p] == code))[0]:
            rows.append(
                Collision(
                    meta.label,
                    meta.model,
                    meta.seed,
                    meta.episode,
                    case=int(c),
                    partner=PARTNERS[int(out["partner"][p][c])],
                    hazard=HAZARDS[int(out["hit_hazard"][p][c])],
                    yielding=bool(info.yielding[c]),
                    hit_speed=float(out["hit_speed"][p][c]),
                    time_s=float(out["steps"][p][c] * dt),
                    **{k: float(getattr(info, k)[c]) for k in COLLISION_FIELDS[-4:]},
                )
            )
    return rows


def in_traffic(cfg: config.Config, overrides: Sequence[str]) -> config.Config:
    """``cfg`` with ``[env]`` overrides (``env.KEY=VALUE``), validated as a config file's
    values are; any other table is refused (the policies are the run's)."""
    data = cfg.to_dict()
    for text in overrides:
        table, key, value = config.parse_override(text)
        if table != "env":
            raise config.ConfigError(
                f"traffic override '{text}': only [env] keys (env.KEY=VALUE) set the traffic"
            )
        data["env"][key] = value
    return config.from_dict(data)


def _g(v: float | tuple[float, float]) -> str:
    """A number, or a range drawn per episode as ``lo–hi``."""
    return "–".join(f"{x:g}" for x in v) if isinstance(v, tuple) else f"{v:g}"


def traffic_of(env: config.EnvConfig) -> str:
    """One line naming the traffic of ``env``: the paper's, or its lane changes and braking
    events with their settings."""
    parts, g = [], _g
    if env.mobil:
        parts.append(
            f"MOBIL lane changes (politeness {g(env.mobil_politeness)}, threshold "
            f"{g(env.mobil_threshold)} m/s², right bias {env.mobil_bias_right:g} m/s², acting at "
            f"{g(env.mobil_rate)}/s, {env.lane_change_time_min:g}–{env.lane_change_time_max:g} s, "
            f"one per {env.mobil_interval:g} s)"
        )
    if env.braking:
        parts.append(
            f"braking events ({g(env.braking_rate)} per vehicle-hour, "
            f"{env.braking_decel_min:g}–{env.braking_decel_max:g} m/s² for "
            f"{env.braking_time_min:g}–{env.braking_time_max:g} s)"
        )
    if not parts:
        return (
            "the paper's traffic (the other vehicles keep their lane and brake only for "
            "their leader)"
        )
    return "traffic with " + " and ".join(parts)


def _two_level(k: np.ndarray, n: np.ndarray, seed: int = 0) -> tuple[float, float]:
    """Interval of the mean over seeds of ``k / n`` ``(seeds,)``: seeds resampled, then each
    drawn seed's lane changes (a binomial draw at its own rate)."""
    rng = np.random.default_rng(seed)
    pick = rng.integers(0, k.size, (RESAMPLES, k.size))
    rates = rng.binomial(n[pick], k[pick] / n[pick]) / n[pick]
    level = expanded_level(k.size)
    lo, hi = np.quantile(rates.mean(axis=1), [(1 - level) / 2, (1 + level) / 2])
    return float(lo), float(hi)


def cell_rows(rows: list[HeldoutRow]) -> list[HeldoutCell]:
    """One record per grid cell of the held-out model rows: the mean success over its seeds
    with its interval, pooled failures and collisions with their bounds, the norms' share."""
    models = [r for r in rows if r.model is not None and r.lane_changes]
    cells = []
    for key in dict.fromkeys(r.axes for r in models):
        mine = [r for r in models if r.axes == key]
        k = np.asarray([r.success for r in mine])
        n = np.asarray([r.lane_changes for r in mine])
        if len(mine) >= MIN_BOOT_SEEDS:
            (lo, hi), how = _two_level(k, n), "two-level bootstrap (seeds, then lane changes)"
        else:
            lo, hi = min(r.success_lo for r in mine), max(r.success_hi for r in mine)
            how = (
                f"range of the {len(mine)} seeds' Clopper-Pearson intervals"
                if len(mine) > 1
                else "Clopper-Pearson interval of the one seed"
            )
        fails, hits, total = int((n - k).sum()), sum(r.collision for r in mine), int(n.sum())
        cells.append(
            HeldoutCell(
                mine[0].label,
                *key,  # the paper's tag: paper.grid.tag_of
                seeds=len(mine),
                lane_changes=total,
                success_mean=float(np.mean(k / n)),
                success_lo=lo,
                success_hi=hi,
                interval=how,
                failures=fails,
                failure_bound=upper_bound(fails, total),
                collisions=hits,
                collision_rate=hits / total,
                collision_bound=upper_bound(hits, total),
                models_without_failure=int(np.sum(k == n)),
                norm_all=float(np.mean([r.norm_all for r in mine])),
                **{h: sum(getattr(r, h) or 0 for r in mine) for h in HAZARD_KEYS},
            )
        )
    return cells


def claim_d(cells: list[HeldoutCell]) -> Claim:
    """Claim (d), "④ succeeds in 100%", as a bound on ④'s held-out failure rate: *supported*
    when the pooled one-sided 95% bound is at most 1 - SOLVED (1%), *not supported* when the
    two-sided interval's lower end lies above it, else undecided."""
    best = next((c for c in cells if is_best(c)), None)
    if best is None:
        return Claim(CLAIM_D, "100%", figures=f"the grid has no {BEST_TAG}")
    fails, n, s = best.failures, best.lane_changes, best.seeds
    lo, _ = clopper_pearson(fails, n)
    bound = best.failure_bound
    if bound <= 1.0 - SOLVED:
        v = "supported"
    elif lo > 1.0 - SOLVED:
        v = "not supported"
    else:
        v = f"undecided at {n} lane changes"
    figures = (
        f"{BEST_TAG} fails in fewer than {100 * bound:.2f}% of held-out lane changes (95%, "
        f"Clopper-Pearson: {fails} failures in {n} over {s} seed{'s' * (s != 1)})"
    )
    return Claim(CLAIM_D, "100%", figures=figures, verdict=v)
