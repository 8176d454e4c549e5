"""Learning speed from the training curves: the measures the paper's claims (a)-(c) rest on.

The paper argues its claims from Fig. 3 (total reward per training episode: "① and ② show
better converging trend than ③", "among ①④⑤, ④ converges fast and has the best
performance", "among ②⑥⑦, ⑦ shows the best performance", "④ converges faster and is
slightly better than ⑦") and Fig. 4a (④'s manoeuvring steps rise earlier than ⑦'s), not from
final success, which every cell of a good run shares. Per model, from
``metrics/episodes.npz`` (noise on, as in the paper's figures):

- ``converged``: the first episode from which the return's moving average (``WINDOW``
  episodes) stays within ``BAND`` of the rise from its start to its plateau (the mean return
  of the last ``PLATEAU`` episodes);
- ``success95``: the first episode at which the success share of the last ``WINDOW``
  episodes reaches 95% (the episode count + 1 when it never does);
- ``auc``: the area under the return's moving average, normalised over the run (0 at the
  run's lowest moving average, 1 at its highest), per episode;
- ``steps_rise``: the first episode at which the moving average of manoeuvre steps reaches
  half of its rise from the start to its peak (Fig. 4a: early episodes end out of bounds in
  a few steps);
- ``plateau``: the plateau return itself (performance, where "best" is about the end).

Each comparison of the paper is decided by the probability of improvement over pairs of
seeds with its bootstrap interval (``jaxlc.evaluation.stats.improvement``: rliable's
definition; fewer episodes is better for the three episode counts, more for ``auc`` and
``plateau``).
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from jaxlc.evaluation import stats
from jaxlc.sim.reward import SUCCESS

WINDOW = 100
PLATEAU = 500
BAND = 0.1
MEASURES = ("converged", "success95", "steps_rise", "auc", "plateau")
LOWER_IS_BETTER = {"converged", "success95", "steps_rise"}
# The paper's comparisons (tag pairs "X better than Y") and the sentence each rests on.
COMPARISONS = (
    (
        "(c) ① and ② converge better than ③ (Fig. 3a)",
        (("①", "③"), ("②", "③")),
        ("converged", "auc"),
    ),
    (
        "(a, b) ④ converges fast and is best of ①④⑤ (Fig. 3b)",
        (("④", "①"), ("④", "⑤")),
        ("converged", "auc", "plateau"),
    ),
    ("(b) ⑦ is best of ②⑥⑦ (Fig. 3c)", (("⑦", "②"), ("⑦", "⑥")), ("auc", "plateau")),
    ("(a) ④ converges faster than ⑦ (Figs. 3d, 4a)", (("④", "⑦"),), ("converged", "steps_rise")),
)


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
        "auc_lo": float(ma.min()),
        "auc_hi": float(ma.max()),
        "plateau": plateau,
    }


def run_measures(episodes: dict[str, np.ndarray]) -> list[dict[str, float]]:
    """Every model's measures from ``metrics/episodes.npz``, ``auc`` normalised over the run."""
    rows = []
    for m in range(episodes["ret"].shape[0]):
        n = int(episodes["episodes"][m])
        rows.append(
            model_measures(
                episodes["ret"][m, :n], episodes["steps"][m, :n], episodes["reason"][m, :n]
            )
        )
    lo, hi = min(r["auc_lo"] for r in rows), max(r["auc_hi"] for r in rows)
    for r in rows:
        r["auc"] = (r["auc"] - lo) / (hi - lo) if hi > lo else math.nan
        del r["auc_lo"], r["auc_hi"]
    return rows


def comparisons(models: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Each of the paper's comparisons on each measure: ``models`` are rows with ``label``
    (starting with the paper's tag) and the measures; one row per pair and measure with
    P(X better than Y), its interval and ``stats.verdict``, where the grid has both cells."""
    by_tag: dict[str, list[dict[str, Any]]] = {}
    for r in models:
        by_tag.setdefault(str(r["label"])[:1], []).append(r)
    out = []
    for claim, pairs, _ in COMPARISONS:
        for x, y in pairs:
            if x not in by_tag or y not in by_tag:
                continue
            n = min(len(by_tag[x]), len(by_tag[y]))
            for m in MEASURES:
                sign = -1.0 if m in LOWER_IS_BETTER else 1.0
                xs = np.asarray([sign * r[m] for r in by_tag[x]])
                ys = np.asarray([sign * r[m] for r in by_tag[y]])
                p, lo, hi = stats.improvement([xs], [ys])
                out.append(
                    {
                        "claim": claim,
                        "x": x,
                        "y": y,
                        "measure": m,
                        "x_mean": float(np.nanmean(sign * xs)),
                        "y_mean": float(np.nanmean(sign * ys)),
                        "seeds": n,
                        "p": p,
                        "p_lo": lo,
                        "p_hi": hi,
                        "verdict": stats.verdict(lo, hi, n),
                    }
                )
    return out


def claim_verdicts(rows: list[dict[str, Any]]) -> list[dict[str, str]]:
    """One verdict per claim from its key measures (``COMPARISONS``): *supported* when every
    pair is supported on every key measure, *not supported* when some pair is not supported
    on one, else undecided at the fewest seeds."""
    out = []
    for claim, _, keys in COMPARISONS:
        mine = [r for r in rows if r["claim"] == claim and r["measure"] in keys]
        if not mine:
            continue
        n = min(r["seeds"] for r in mine)
        vs = [r["verdict"] for r in mine]
        if all(v == "supported" for v in vs):
            v = "supported"
        elif any(v == "not supported" for v in vs):
            v = "not supported"
        else:
            v = stats.verdict(math.nan, math.nan, n)
        figures = "; ".join(
            f"P({r['x']} > {r['y']}) on {r['measure']} = {r['p']:.2f} [{r['p_lo']:.2f}, "
            f"{r['p_hi']:.2f}]"
            for r in mine
        )
        out.append({"claim": claim, "measures": ", ".join(keys), "figures": figures, "verdict": v})
    return out


def study(episodes: dict[str, np.ndarray], models: list[dict[str, Any]]) -> dict[str, Any]:
    """The content of ``eval/convergence.json``: per model (``summary.json``'s ``models``,
    whose ``model`` indexes ``episodes``) its measures, then the comparisons and verdicts."""
    keep = ("model", "cell", "seed", "label", "k", "memory")
    per = run_measures(episodes)
    rows = [{**{k: m.get(k) for k in keep}, **per[m["model"]]} for m in models]
    comps = comparisons(rows)
    return {
        "window": WINDOW,
        "plateau_episodes": PLATEAU,
        "band": BAND,
        "models": rows,
        "comparisons": comps,
        "claims": claim_verdicts(comps),
    }
