"""What an evaluation result is: outcome buckets, measures, row fields, ranking.

One module that the evaluation (``jaxlc.evaluate``), the figures and the report all read, so
none of them imports another for a definition. A *row* is one policy's result on the fixed
cases: its identity (``META_KEYS``), outcome counts (``OUTCOMES``, adding up to the cases) and
its ``measures`` (one per reward term of the run among them).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from jaxlc.evaluation.numbers import defined
from jaxlc.evaluation.stats import CELL_AXES, final_rows
from jaxlc.sim.reward import PAPER, REASONS

OUTCOMES = ("unfinished",) + REASONS[1:]  # index = reason code; 0: hit the step cap
PAPER_TERMS = tuple(t.name for t in PAPER)  # the default env.reward_terms


def measures(terms: Sequence[str] = PAPER_TERMS) -> tuple[str, ...]:
    """A row's measures; each reward term (``env.reward_terms``) is one, by its name."""
    return (
        "success_rate",
        "avg_return",
        "duration_s",
        "peak_lat_acc",
        "peak_yaw_rate",
        "overshoot_m",
        *terms,
        "timeout_offset_m",
        "timeout_heading",
        "timeout_yaw_rate",
    )


def eval_fields(terms: Sequence[str] = PAPER_TERMS) -> tuple[str, ...]:
    """The columns of ``eval.csv`` for a run whose reward has ``terms``."""
    return (
        ("label", "model", "cell", "seed", "k", "memory", "episode", "cases", "performed")
        + OUTCOMES
        + measures(terms)
    )


MEASURES = measures()  # with the paper's reward terms


class EvalError(Exception):
    """The evaluation cannot run; the message names the problem and the fix."""


# The cell's axes beside k and memory, so that runs can be matched cell by cell (stats).
META_KEYS = ("label", "model", "seed", "k", "memory", "episode", "cell") + CELL_AXES[2:]
SCRIPTED = {"label": "scripted controller", **dict.fromkeys(META_KEYS[1:]), "checkpoint": None}


def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if values.size else math.nan


def _median_abs(values: np.ndarray) -> float:
    return float(np.median(np.abs(values))) if values.size else math.nan


def summarise(
    out: dict[str, np.ndarray], dt: float, terms: Sequence[str] = PAPER_TERMS
) -> list[dict[str, Any]]:
    """One row per policy: outcome counts (they add up to the cases) and the measures.

    Return and reward terms average over the cases that performed a lane change; duration,
    peak lateral acceleration, peak yaw rate and overshoot over the successful ones, which is
    what compares with human lane changes (~3-8 s). ``timeout_*`` are medians over the
    timeouts of the final |offset| (m), |heading| (rad) and |yaw rate| (rad/s), to set beside
    the success box.
    """
    rows = []
    for p in range(out["reason"].shape[0]):
        reason, performed = out["reason"][p], out["performed"][p]
        ok = reason == OUTCOMES.index("success")
        late = reason == OUTCOMES.index("timeout")
        n_perf = int(performed.sum())
        rows.append(
            {
                "cases": int(reason.size),
                "performed": n_perf,
                **{name: int((reason == code).sum()) for code, name in enumerate(OUTCOMES)},
                "success_rate": float(ok.sum() / n_perf) if n_perf else math.nan,
                "avg_return": _mean(out["ret"][p][performed]),
                "duration_s": _mean(out["steps"][p][ok] * dt),
                "peak_lat_acc": _mean(out["peak_lat_acc"][p][ok]),
                "peak_yaw_rate": _mean(out["peak_yaw_rate"][p][ok]),
                "overshoot_m": _mean(out["overshoot"][p][ok]),
                **{t: _mean(out[t][p][performed]) for t in terms},
                "timeout_offset_m": _median_abs(out["final_offset"][p][late]),
                "timeout_heading": _median_abs(out["final_psi"][p][late]),
                "timeout_yaw_rate": _median_abs(out["final_omega"][p][late]),
            }
        )
    return rows


def rank_key(row: dict[str, Any]) -> tuple[float, float]:
    """A row's (or a cell's) place, higher first: its success rate, then its average return;
    an undefined one (no lane change performed) below every number."""
    sr, ret = row["success_rate"], row["avg_return"]
    return (sr if defined(sr) else -1.0, ret if defined(ret) else -math.inf)


def rank_models(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Final-checkpoint rows, best first (``rank_key``)."""
    return sorted(final_rows(rows), key=rank_key, reverse=True)


def format_table(rows: list[dict[str, Any]]) -> str:
    """Plain-text table of the evaluation rows for the terminal."""
    head = "policy                    seed    ep  perf  succ%   return  " + " ".join(
        f"{o[:4]:>4}" for o in OUTCOMES[1:] + OUTCOMES[:1]
    )
    lines = [head]
    for r in rows:
        sr = "   -" if r["success_rate"] != r["success_rate"] else f"{100 * r['success_rate']:5.1f}"
        ret = "      -" if r["avg_return"] != r["avg_return"] else f"{r['avg_return']:8.1f}"
        counts = " ".join(f"{r[o]:4d}" for o in OUTCOMES[1:] + OUTCOMES[:1])
        lines.append(
            f"{r['label'][:26]:26} {'-' if r['seed'] is None else r['seed']:>4} "
            f"{r['episode'] or '-':>5} {r['performed']:5d} {sr:>6} "
            f"{ret:>8}  {counts}"
        )
    return "\n".join(lines)
