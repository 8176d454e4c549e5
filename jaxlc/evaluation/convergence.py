"""Learning speed from the training curves (``metrics/episodes.npz``, noise on): the measures the
paper's claims (a)-(c) rest on (docs/usage.md, "Learning speed, the paper's way"; the paper
argues them from Fig. 3 and Fig. 4a, not from final success, which a good run's cells share).

Per model (``model_measures``): ``converged``, the first episode from which the return's
moving average (``WINDOW``) stays within ``BAND`` of its rise to the plateau (the mean of the
last ``PLATEAU`` episodes); ``success95``, the first episode with 95% success over the last
``WINDOW`` (episodes + 1 if never); ``auc``, the area under the return's moving average,
normalised over the run; ``steps_rise``, the first episode the manoeuvre steps' moving average
reaches half its rise; ``plateau``.

Each comparison "X better than Y" on a measure is decided (``decide``) on the paper-side
difference of the cells' means over seeds (fewer episodes, more ``auc`` or ``plateau``) and
its 95% bootstrap interval (``stats.difference``), against ``MARGIN`` of the measure's axis
(docs/decisions.md, "margins of the learning-speed comparisons"): *no practical difference*
inside (-margin, +margin), *holds* above 0, *fails* below, else *undecided*, and always below
``stats.RANGE_BELOW`` seeds per cell. P(X > Y) is given beside it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from typing import Any

import numpy as np

from jaxlc.evaluation import stats
from jaxlc.evaluation.numbers import Record, fixed, many
from jaxlc.evaluation.results import Claim
from jaxlc.paper.claims import COMPARISONS
from jaxlc.paper.grid import tag_of
from jaxlc.sim.reward import SUCCESS


@dataclass
class Speed(Record):
    """One model's learning speed from its training curves (``convergence.model_measures``)."""

    model: int | None = None
    cell: int | None = None
    seed: int | None = None
    label: str | None = None
    k: int | None = None
    memory: int | None = None
    actor_lr: float | None = None
    critic_lr: float | None = None
    noise_sigma: float | None = None
    converged: float | None = None
    success95: float | None = None
    steps_rise: float | None = None
    auc: float | None = None
    plateau: float | None = None


@dataclass
class Comparison(Record):
    """One of the paper's comparisons "x better than y" on one measure: the cells' means, P(x
    better than y), the paper-side difference of means with its interval, the margin."""

    claim: str = ""
    x: str = ""
    y: str = ""
    measure: str = ""
    x_mean: float | None = None
    y_mean: float | None = None
    seeds: int = 0
    p: float | None = None
    p_lo: float | None = None
    p_hi: float | None = None
    diff: float | None = None
    diff_lo: float | None = None
    diff_hi: float | None = None
    margin: float | None = None
    verdict: str = ""


@dataclass
class Convergence(Record):
    """``convergence.json``: the settings of the measures, each model's, the comparisons and
    the claims (a)-(c)."""

    window: int = 0
    plateau_episodes: int = 0
    band: float = 0.0
    margin_share: float | None = None
    margins: dict[str, float] | None = None
    models: list[Speed] = many(Speed)
    comparisons: list[Comparison] = many(Comparison)
    claims: list[Claim] = many(Claim)


WINDOW = 100
PLATEAU = 500
BAND = 0.1
MEASURES = ("converged", "success95", "steps_rise", "auc", "plateau")
LOWER_IS_BETTER = {"converged", "success95", "steps_rise"}
# The margin of "no practical difference" (module docstring): a share of the axis each
# measure lives on; the episode counts' axis is the training episodes, ``plateau``'s the run's
# return range, ``auc``'s the unit range it is normalised to.
MARGIN = 0.02
HOLDS, FAILS, SAME = "holds", "fails", "no practical difference"


def moving(x: np.ndarray, window: int = WINDOW) -> np.ndarray:
    """Trailing moving average ``(n,) -> (n - window + 1,)``, NaNs ignored (the whole mean if
    shorter than the window); the figures' curves are drawn with it too."""
    x = np.asarray(x, float)
    if x.size < window:
        return np.asarray([np.nanmean(x)]) if x.size else x
    ok = np.isfinite(x)
    kernel = np.ones(window)
    total = np.convolve(np.where(ok, x, 0.0), kernel, "valid")
    count = np.convolve(ok.astype(float), kernel, "valid")
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / count


def _first(mask: np.ndarray, default: int) -> int:
    """Episode (1-based, at the end of its window) of the first True; ``default`` if none."""
    return int(np.argmax(mask)) + WINDOW if mask.any() else default


def first_stays(curve: np.ndarray, target: float, band: float) -> int:
    """First index from which ``curve`` stays within ``band`` of ``target`` (len if never)."""
    outside = np.abs(curve - target) > band
    return int(np.nonzero(outside)[0][-1]) + 1 if outside.any() else 0


def model_measures(ret: np.ndarray, steps: np.ndarray, reason: np.ndarray) -> dict[str, float]:
    """The measures of one model from its episodes ``(episodes,)``; ``auc`` unnormalised
    (the mean of the return's moving average; ``run_measures`` scales it over a run)."""
    n = ret.size
    ma = moving(ret)
    plateau = float(np.mean(ret[-PLATEAU:]))
    band = BAND * abs(plateau - ma[0])
    ok = moving(reason == SUCCESS)
    st = moving(steps)
    half = st[0] + 0.5 * (st.max() - st[0])
    return {
        "converged": float(first_stays(ma, plateau, band) + WINDOW),
        "success95": float(_first(ok >= 0.95, n + 1)),
        "steps_rise": float(_first(st >= half, n + 1)) if st.max() > st[0] else math.nan,
        "auc": float(ma.mean()),
        "plateau": plateau,
    }


def _runs(episodes: dict[str, np.ndarray]) -> list[tuple[np.ndarray, ...]]:
    """Each model's ``(ret, steps, reason)`` over its episodes (``metrics/episodes.npz``)."""
    cols = (episodes["ret"], episodes["steps"], episodes["reason"])
    return [tuple(c[m, : int(n)] for c in cols) for m, n in enumerate(episodes["episodes"])]


def _span(runs: list[tuple[np.ndarray, ...]]) -> tuple[float, float]:
    """The lowest and highest moving average of any model's return."""
    curves = [moving(ret) for ret, *_ in runs]
    return float(min(map(np.min, curves))), float(max(map(np.max, curves)))


def run_measures(episodes: dict[str, np.ndarray]) -> list[dict[str, float]]:
    """Every model's measures from ``metrics/episodes.npz``, ``auc`` normalised over the run."""
    runs = _runs(episodes)
    rows, (lo, hi) = [model_measures(*r) for r in runs], _span(runs)
    for r in rows:
        r["auc"] = (r["auc"] - lo) / (hi - lo) if hi > lo else math.nan
    return rows


def margins(episodes: dict[str, np.ndarray]) -> dict[str, float]:
    """Each measure's margin of "no practical difference" for a run (``MARGIN`` of its
    axis): episodes for the episode counts, return for ``plateau``, unit for ``auc``."""
    n = int(np.max(episodes["episodes"]))
    lo, hi = _span(_runs(episodes))
    # In MEASURES' order: the set's would follow the process's string hashing, and the
    # margins' order in convergence.json would change from one run to the next.
    out = {m: MARGIN * n for m in MEASURES if m in LOWER_IS_BETTER}
    return out | {"auc": MARGIN, "plateau": MARGIN * (hi - lo)}


def decide(lo: float, hi: float, margin: float, seeds: int) -> str:
    """The decision of one comparison from the interval ``[lo, hi]`` of its paper-side
    difference (module docstring)."""
    if seeds < stats.RANGE_BELOW or not (math.isfinite(lo) and math.isfinite(hi)):
        return f"undecided at {seeds} seed{'s' * (seeds != 1)}"
    if -margin < lo and hi < margin:
        return SAME
    if lo > 0:
        return HOLDS
    if hi < 0:
        return FAILS
    return f"undecided (interval width {hi - lo:.3g}, margin ±{margin:.3g})"


def comparisons(models: list[Speed], margin: dict[str, float] | None = None) -> list[Comparison]:
    """Each of the paper's comparisons on each measure: ``models`` are rows with ``k``,
    ``memory`` (the paper's tag: ``paper.grid.tag_of``) and the measures; one row per pair
    and measure where the grid has both cells, with the paper-side difference of means
    ``diff`` (its interval ``diff_lo``, ``diff_hi``), the ``margin`` (``margins``; NaN: none
    given, so nothing is "no practical difference"), the ``verdict`` (``decide``) and
    P(X better than Y) with its interval."""
    margin = margin or {}
    by_tag: dict[str | None, list[Speed]] = {}
    for r in models:
        by_tag.setdefault(tag_of(r), []).append(r)
    out = []
    for claim, pairs, _ in COMPARISONS:
        for x, y in pairs:
            if x not in by_tag or y not in by_tag:
                continue
            n = min(len(by_tag[x]), len(by_tag[y]))
            for m in MEASURES:
                sign = -1.0 if m in LOWER_IS_BETTER else 1.0
                xs = np.asarray([sign * getattr(r, m) for r in by_tag[x]])
                ys = np.asarray([sign * getattr(r, m) for r in by_tag[y]])
                p, lo, hi = stats.improvement([xs], [ys])
                d, d_lo, d_hi = stats.difference(ys, xs)  # mean(xs) - mean(ys), paper side +
                room = margin.get(m, math.nan)
                out.append(
                    Comparison(
                        claim,
                        x,
                        y,
                        m,
                        float(np.nanmean(sign * xs)),
                        float(np.nanmean(sign * ys)),
                        n,
                        p,
                        lo,
                        hi,
                        d,
                        d_lo,
                        d_hi,
                        room,
                        decide(d_lo, d_hi, room if room == room else 0.0, n),
                    )
                )
    return out


def claim_verdicts(rows: list[Comparison]) -> list[Claim]:
    """One verdict per claim from its comparisons on its key measures (``COMPARISONS``):
    *fails* when one fails; else undecided when one is; else *holds* or *no practical
    difference* when all agree, and when they mix, which measures hold and which show none."""
    out = []
    for claim, pairs, keys in COMPARISONS:
        mine = [r for r in rows if r.claim == claim and r.measure in keys]
        if not mine:  # the claim is still named, so every report lists the same claims
            tags = "".join(dict.fromkeys(t for pair in pairs for t in pair))
            out.append(Claim(claim, None, ", ".join(keys), f"the grid lacks a cell of {tags}"))
            continue
        vs = [r.verdict for r in mine]
        if FAILS in vs:
            v = FAILS
        elif any(x.startswith("undecided") for x in vs):
            n = min(r.seeds for r in mine)
            v = f"undecided at {n} seed{'s' * (n != 1)}"
            if n >= stats.RANGE_BELOW:  # the intervals that stayed too wide, and how wide
                wide = [r for r in mine if r.verdict.startswith("undecided")]
                v += " (" + "; ".join(_width(r) for r in wide) + ")"
        elif len(set(vs)) == 1:
            v = vs[0]
        else:
            held = sorted({r.measure for r in mine if r.verdict == HOLDS})
            v = f"{HOLDS} on {', '.join(held)}; {SAME} on the rest"
        figures = "; ".join(
            f"{r.measure}: {r.x} ahead of {r.y} by {fixed(r.diff, '.3g')} "
            f"[{fixed(r.diff_lo, '.3g')}, {fixed(r.diff_hi, '.3g')}] "
            f"(margin ±{fixed(r.margin, '.3g')})"
            for r in mine
        )
        out.append(Claim(claim, None, ", ".join(keys), figures, v))
    return out


def _width(r: Comparison) -> str:
    """How wide an undecided comparison's interval stayed, beside its margin."""
    width, margin = fixed(r.diff_hi - r.diff_lo, ".3g"), fixed(r.margin, ".3g")
    return f"{r.measure} {r.x}−{r.y}: interval {width} wide, margin ±{margin}"


def study(episodes: dict[str, np.ndarray], models: list[dict[str, Any]]) -> Convergence:
    """The content of ``eval/convergence.json``: per model (``summary.json``'s ``models``,
    whose ``model`` indexes ``episodes``) its measures, then the comparisons and verdicts."""
    keep = [f.name for f in fields(Speed)[:9]]  # the model's identity
    per = run_measures(episodes)
    rows = [Speed(**{k: m.get(k) for k in keep}, **per[m["model"]]) for m in models]
    room = margins(episodes)
    comps = comparisons(rows, room)
    return Convergence(WINDOW, PLATEAU, BAND, MARGIN, room, rows, comps, claim_verdicts(comps))
