"""Statistics over seeds (docs/usage.md, "Statistics over seeds"): intervals, probability of
improvement, performance profiles, from the rows of ``eval/eval.json``; pure numpy/scipy.

A *cell* is one ``(k, memory, actor_lr, critic_lr, noise_sigma)``, its models one per seed.
Intervals are 95% percentile bootstraps (``scipy.stats.bootstrap``, ``RESAMPLES``, a fixed
generator), stratified: each cell's seeds resampled within it, two cells or runs on their
own, at Hesterberg's expanded level (``expanded_level``; n the fewest seeds of a sample).
Below ``RANGE_BELOW`` seeds a cell's interval of a mean is its seeds' range; with one seed
there is none (NaN). P(X > Y) counts ties half; the claims: ``convergence`` (a)-(c),
``heldout.claim_d`` (d).
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.stats

from jaxlc.evaluation.numbers import Record, many, number, optional
from jaxlc.evaluation.results import CELL_AXES, CellId, Row, final_rows

CONFIDENCE = 0.95
RESAMPLES = 2000
BATCH = 250  # resamples per vectorised call: bounds memory for figure bands of many points
TAUS = np.linspace(0.0, 1.0, 101)
SEEDS_NOTE = "intervals need >= 2 seeds per cell"
RANGE_BELOW = 5  # fewer seeds: a cell's "interval" of a mean is the seeds' range (describe)
RANGE_NOTE = "with fewer than 5 seeds a cell's interval is the range of its seeds"


@dataclass
class SeedCell(CellId):
    """A cell's success and return over its seeds at one checkpoint ``episode`` (None: each
    model's last), mean and IQM with their intervals (``stats.describe``)."""

    episode: int | None = optional()
    seeds: int = 0
    success_mean: float | None = None
    success_mean_lo: float | None = None
    success_mean_hi: float | None = None
    success_iqm: float | None = None
    success_iqm_lo: float | None = None
    success_iqm_hi: float | None = None
    return_mean: float | None = None
    return_mean_lo: float | None = None
    return_mean_hi: float | None = None
    return_iqm: float | None = None
    return_iqm_lo: float | None = None
    return_iqm_hi: float | None = None


@dataclass
class Improvement(Record):  # P(x > y) of the final success rate of two cells
    x: str = ""
    y: str = ""
    seeds_x: int = 0
    seeds_y: int = 0
    p: float | None = None
    p_lo: float | None = None
    p_hi: float | None = None


@dataclass
class Difference(CellId):
    """Run B's mean success rate minus run A's in one cell at one checkpoint (``compare``)."""

    episode: int | None = None
    seeds_a: int = 0
    seeds_b: int = 0
    success_a: float | None = None
    success_b: float | None = None
    diff: float | None = None
    diff_lo: float | None = None
    diff_hi: float | None = None


@dataclass
class SeedStats(Record):
    """``cells.json``: per cell and checkpoint, per cell at the end, P(X > Y) of each pair."""

    confidence: float = 0.95
    resamples: int = 0
    note: str | None = None
    cells: list[SeedCell] = many(SeedCell)
    final: list[SeedCell] = many(SeedCell)
    improvement: list[Improvement] = many(Improvement)


class StatsError(ValueError):
    """Data that cannot be compared; the message names the difference."""


# --------------------------------------------------------------------------- intervals


def expanded_level(n: int, confidence: float = CONFIDENCE) -> float:
    """Percentile level that makes a bootstrap interval of ``n`` observations cover about
    ``confidence`` (Hesterberg's expanded percentile interval); NaN below 2."""
    if n < 2:
        return math.nan
    z = math.sqrt(n / (n - 1)) * scipy.stats.t.ppf(0.5 + confidence / 2, n - 1)
    # At 2 seeds the level rounds to 1, which scipy refuses; the interval is then the
    # range of the resampled statistic either way.
    return min(1.0 - 2.0 * scipy.stats.norm.sf(z), 1.0 - 1e-9)


def interval(
    samples: Sequence[np.ndarray], statistic: Callable[..., np.ndarray], seed: int = 0
) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` bootstrap interval of ``statistic(*samples, axis=-1)``, each sample
    resampled on its own along its last axis (stratified); NaN where a sample has < 2.

    ``samples``: arrays ``(..., n_i)``; ``statistic`` reduces the last axis and puts any
    axes of its own first (scipy keeps resamples last)."""
    samples = [np.asarray(s, float) for s in samples]
    n = min(s.shape[-1] for s in samples)
    if n < 2:
        nan = np.full(np.shape(statistic(*samples, axis=-1)), np.nan)
        return nan, nan
    res = scipy.stats.bootstrap(
        tuple(samples),
        statistic,
        vectorized=True,
        paired=False,
        axis=-1,
        n_resamples=RESAMPLES,
        batch=BATCH,
        confidence_level=expanded_level(n),
        method="percentile",
        rng=np.random.default_rng(seed),
    )
    return np.asarray(res.confidence_interval.low), np.asarray(res.confidence_interval.high)


def iqm(x: np.ndarray, axis: int = -1) -> np.ndarray:
    """Interquartile mean: the mean of the middle 50% along ``axis``."""
    return scipy.stats.trim_mean(x, 0.25, axis=axis)


def _mean_iqm(x: np.ndarray, axis: int = -1) -> np.ndarray:
    return np.stack([np.mean(x, axis=axis), iqm(x, axis=axis)])


def _finite(x: Any) -> np.ndarray:
    x = np.asarray(x, float)
    return x[np.isfinite(x)]


def describe(x: np.ndarray, seed: int = 0) -> dict[str, float]:
    """Mean and IQM of ``x`` ``(seeds,)`` (NaNs dropped) with their intervals."""
    x, keys = _finite(x), ("mean", "mean_lo", "mean_hi", "iqm", "iqm_lo", "iqm_hi")
    if x.size == 0:
        return dict.fromkeys(keys, math.nan)
    est = _mean_iqm(x)
    if 2 <= x.size < RANGE_BELOW:
        # No bootstrap covers at so few seeds; say plainly that this is the seeds' range.
        lo, hi = np.full(2, x.min()), np.full(2, x.max())
    else:
        lo, hi = interval([x], _mean_iqm, seed)
    return dict(zip(keys, (float(v[i]) for i in (0, 1) for v in (est, lo, hi)), strict=True))


def prob_improvement(x: np.ndarray, y: np.ndarray, axis: int = -1) -> np.ndarray:
    """``P(X > Y) + 0.5 P(X = Y)`` over every pair of an ``x`` and a ``y`` along ``axis``
    (``x (..., n)``, ``y (..., m)`` -> ``(...)``)."""
    x = np.moveaxis(np.asarray(x, float), axis, -1)[..., :, None]
    y = np.moveaxis(np.asarray(y, float), axis, -1)[..., None, :]
    return np.mean((x > y) + 0.5 * (x == y), axis=(-2, -1))


def improvement(
    xs: Sequence[np.ndarray], ys: Sequence[np.ndarray], seed: int = 0
) -> tuple[float, float, float]:
    """``(P(X > Y), lo, hi)``; X pools the seeds of the cells ``xs`` (each ``(seeds,)``),
    Y those of ``ys``, each cell resampled within itself."""
    xs, ys = [_finite(x) for x in xs], [_finite(y) for y in ys]
    if not sum(x.size for x in xs) or not sum(y.size for y in ys):
        return math.nan, math.nan, math.nan
    n = len(xs)

    def stat(*s: np.ndarray, axis: int = -1) -> np.ndarray:
        return prob_improvement(np.concatenate(s[:n], axis), np.concatenate(s[n:], axis), axis)

    lo, hi = interval([*xs, *ys], stat, seed)
    return float(stat(*xs, *ys)), float(lo), float(hi)


def difference(a: np.ndarray, b: np.ndarray, seed: int = 0) -> tuple[float, float, float]:
    """``(mean(b) - mean(a), lo, hi)`` of two independent samples ``(seeds,)``."""
    a, b = _finite(a), _finite(b)
    if not a.size or not b.size:
        return math.nan, math.nan, math.nan

    def stat(a: np.ndarray, b: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.mean(b, axis=axis) - np.mean(a, axis=axis)

    lo, hi = interval([a, b], stat, seed)
    return float(stat(a, b)), float(lo), float(hi)


def performance_profile(
    samples: Sequence[np.ndarray], taus: np.ndarray = TAUS, seed: int = 0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(share, lo, hi)``, each ``(taus,)``: the share of the models of ``samples`` (cells,
    each ``(seeds,)`` of success rates) whose success is above each ``tau``."""
    samples = [_finite(s) for s in samples]

    def stat(*s: np.ndarray, axis: int = -1) -> np.ndarray:
        above = np.concatenate(s, axis)[..., None] > taus  # (..., models, taus)
        return np.moveaxis(np.mean(above, axis=-2), -1, 0)

    lo, hi = interval(samples, stat, seed)
    return stat(*samples), lo, hi


def mean_band(curves: np.ndarray, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """``(lo, hi)`` ``(points,)``: interval of the mean over seeds of ``curves (seeds,
    points)`` at each point (NaN-aware, for training curves with gaps)."""

    def stat(x: np.ndarray, axis: int = -1) -> np.ndarray:
        return np.nanmean(x, axis=axis)

    with warnings.catch_warnings():  # all-NaN points (no loss before updates start)
        warnings.simplefilter("ignore", RuntimeWarning)
        return interval([np.asarray(curves, float).T], stat, seed)


# --------------------------------------------------------------------------- cells


@dataclass(frozen=True)
class Cell:
    """One grid cell's evaluated models; NaN where a seed lacks that checkpoint or no case
    performed a lane change."""

    key: tuple  # values of CELL_AXES
    label: str
    seeds: tuple[int, ...]
    episodes: tuple[int, ...]
    success: np.ndarray  # (episodes, seeds) success rate
    ret: np.ndarray  # (episodes, seeds) average return
    final_success: np.ndarray  # (seeds,) at each model's last evaluated checkpoint
    final_ret: np.ndarray  # (seeds,)

    @property
    def axes(self) -> dict[str, Any]:
        return dict(zip(CELL_AXES, self.key, strict=True))


def cells_of(rows: list[Row]) -> list[Cell]:
    """The cells of eval.json rows, in the order of their first model."""
    models = [r for r in rows if r.model is not None]
    finals = {r.model: r for r in final_rows(rows)}
    cells = []
    for key in dict.fromkeys(r.axes for r in models):
        mine = [r for r in models if r.axes == key]
        seeds = sorted({r.seed for r in mine}, key=lambda s: (s is None, s))
        episodes = sorted({r.episode for r in mine})
        shape = (len(episodes), len(seeds))
        success, ret = np.full(shape, np.nan), np.full(shape, np.nan)
        for r in mine:
            at = episodes.index(r.episode), seeds.index(r.seed)
            success[at], ret[at] = number(r.success_rate), number(r.avg_return)
        last = [finals[next(r.model for r in mine if r.seed == s)] for s in seeds]
        cells.append(
            Cell(
                key=key,
                label=mine[0].label,
                seeds=tuple(seeds),
                episodes=tuple(episodes),
                success=success,
                ret=ret,
                final_success=np.asarray([number(r.success_rate) for r in last]),
                final_ret=np.asarray([number(r.avg_return) for r in last]),
            )
        )
    return cells


def fewest_seeds(cells: Sequence[Cell]) -> int:
    return min((len(c.seeds) for c in cells), default=0)


def seeds_note(cells: Sequence[Cell]) -> str | None:
    """Why there are no intervals, or that they are the seeds' range (2-4 seeds); None from
    5 seeds per cell on."""
    n = fewest_seeds(cells)
    if n >= RANGE_BELOW:
        return None
    if n >= 2:
        return f"{RANGE_NOTE}; this run has {n} in its smallest cell"
    return f"{SEEDS_NOTE}; this run has {n} seed{'s' * (n != 1)} in its smallest cell"


def _described(c: Cell, success: np.ndarray, ret: np.ndarray, **kw: Any) -> SeedCell:
    both = {
        f"{m}_{k}": v
        for m, x in (("success", success), ("return", ret))
        for k, v in describe(x).items()
    }
    return SeedCell(c.label, *c.key, **kw, **both)


def cell_table(cells: Sequence[Cell]) -> list[SeedCell]:
    """One row per cell and checkpoint episode: seeds, then mean and IQM (with intervals)
    of the success rate and of the average return over the seeds."""
    return [
        _described(c, c.success[i], c.ret[i], episode=e, seeds=int(np.isfinite(c.ret[i]).sum()))
        for c in cells
        for i, e in enumerate(c.episodes)
    ]


def final_table(cells: Sequence[Cell]) -> list[SeedCell]:
    """As ``cell_table`` at each model's last evaluated checkpoint, one row per cell."""
    return [_described(c, c.final_success, c.final_ret, seeds=len(c.seeds)) for c in cells]


def improvement_table(cells: Sequence[Cell]) -> list[Improvement]:
    """P(X > Y) of the final success rate for every ordered pair of different cells."""
    return [
        Improvement(
            x.label,
            y.label,
            len(x.seeds),
            len(y.seeds),
            *improvement([x.final_success], [y.final_success]),
        )
        for x in cells
        for y in cells
        if x is not y
    ]


# --------------------------------------------------------------------------- two runs


def compare(a: Sequence[Cell], b: Sequence[Cell]) -> list[Difference]:
    """Per cell and checkpoint episode that both runs evaluated, the mean success rate of run
    B minus run A with its interval (the runs' seeds resampled independently). Raises
    ``StatsError`` when the runs' cells differ or a cell has no checkpoint episode in both."""
    ka, kb = {c.key: c for c in a}, {c.key: c for c in b}
    if set(ka) != set(kb):
        only_a = [ka[k].label for k in ka if k not in kb]
        only_b = [kb[k].label for k in kb if k not in ka]
        raise StatsError(
            f"the runs' grid cells differ (only in A: {only_a or 'none'}; only in B: "
            f"{only_b or 'none'}); compare runs of the same grid"
        )
    rows = []
    for key, ca in ka.items():
        cb = kb[key]
        common = sorted(set(ca.episodes) & set(cb.episodes))
        if not common:
            raise StatsError(
                f"the runs' checkpoint episodes of {ca.label} have none in common (A: "
                f"{list(ca.episodes)}; B: {list(cb.episodes)}); evaluate both with the same "
                "--episodes"
            )
        for e in common:
            sa, sb = ca.success[ca.episodes.index(e)], cb.success[cb.episodes.index(e)]
            rows.append(
                Difference(
                    ca.label,
                    *key,
                    episode=e,
                    seeds_a=int(np.isfinite(sa).sum()),
                    seeds_b=int(np.isfinite(sb).sum()),
                    success_a=float(np.nanmean(sa)) if np.isfinite(sa).any() else math.nan,
                    success_b=float(np.nanmean(sb)) if np.isfinite(sb).any() else math.nan,
                    **dict(zip(("diff", "diff_lo", "diff_hi"), difference(sa, sb), strict=True)),
                )
            )
    return rows
