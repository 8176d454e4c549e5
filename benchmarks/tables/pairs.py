"""``ddpg.mirror_pairs`` against mirrored batches of rows, two GPU studies each with the rule
it was decided by (its ``rule.md``); the first, of ten seeds per cell, retired by issue 76
(``git show b98c04d:benchmarks/study_pairs_gpu_s10/README.md``)."""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from benchmarks.tables.common import BENCHMARKS, csv_rows, per_cell
from benchmarks.tables.common import per_seed as values_per_seed
from jaxlc.evaluation.convergence import Speed
from jaxlc.evaluation.results import HeldoutRow

PAIRS_STUDY_S20 = BENCHMARKS / "study_pairs_gpu_s20"  # twenty seeds, rows20, pairs20, rows20b


def pairs_table(
    study: Path,
    rows: str,
    pairs: str,
    margin: float | None = None,
    spread: str | None = None,
) -> str:
    """``ddpg.mirror_pairs`` against mirrored batches of rows reflected at random, on one GPU
    (``study``, its runs ``rows`` and ``pairs``): per cell, held-out success and failures, and
    the convergence measures the verdict uses; then the pooled held-out difference with a 95%
    bootstrap interval (seeds resampled within cells, 10,000 resamples, generator seed 0) and
    the answer of the study's ``rule.md``, stated before its run. ``margin`` None: the first
    study's rule (an interval reaching 0, no cell 0.5 points lower); a margin (a share): the
    second's (the interval's lower end at or above -margin, no cell 0.5 points lower, no cell's
    ``auc`` 0.02 lower or ``converged`` 100 episodes later). ``spread``: a run of the rows on
    other seeds, whose difference from ``rows`` is given beside, outside the rule."""
    names = (rows, pairs) + ((spread,) if spread else ())
    held = {r: csv_rows(study / r / "eval" / "heldout.csv", HeldoutRow) for r in names}
    conv = {r: csv_rows(study / r / "eval" / "convergence.csv", Speed) for r in names}
    lines = [
        "| cell | held-out success (rows; pairs) | failures (rows; pairs) "
        "| auc (rows; pairs) | converged, episode (rows; pairs) |",
        "|---|---|---|---|---|",
    ]
    per_seed = {r: values_per_seed(held[r], "success_rate") for r in names}
    success = {r: per_cell(held[r], "success_rate") for r in names}
    auc = {r: per_cell(conv[r], "auc") for r in names}
    converged = {r: per_cell(conv[r], "converged") for r in names}

    def failures(r: str, label: str | None = None) -> int:
        rows_ = [x for x in held[r] if x.cell is not None and label in (None, x.label)]
        return sum(x.lane_changes - x.success for x in rows_)

    for label in success[rows]:
        lines.append(
            f"| {label} | {100 * success[rows][label]:.2f}%; {100 * success[pairs][label]:.2f}% "
            f"| {failures(rows, label)}; {failures(pairs, label)} | "
            f"{auc[rows][label]:.3f}; {auc[pairs][label]:.3f} | "
            f"{converged[rows][label]:.0f}; {converged[pairs][label]:.0f} |"
        )
    rng = np.random.default_rng(0)

    def pooled(cells: dict[str, np.ndarray], resample: bool) -> float:
        pick = (lambda v: rng.choice(v, v.size)) if resample else (lambda v: v)
        return float(np.mean([pick(v).mean() for v in cells.values()]))

    def difference(a: str, b: str) -> tuple[float, float, float]:
        point = pooled(per_seed[b], False) - pooled(per_seed[a], False)
        boot = [pooled(per_seed[b], True) - pooled(per_seed[a], True) for _ in range(10_000)]
        lo, hi = np.percentile(boot, [2.5, 97.5])
        return point, float(lo), float(hi)

    point, lo, hi = difference(rows, pairs)
    worst = min(success[pairs][c] - success[rows][c] for c in success[rows])
    models = sum(1 for x in held[rows] if x.cell is not None)
    said = (
        f"Held-out success pooled over the {models} models, pairs − rows: {100 * point:+.3f} "
        f"points, 95% interval [{100 * lo:+.3f}, {100 * hi:+.3f}]; the largest drop in a cell "
        f"{100 * -worst:.2f} points."
    )
    if margin is None:
        adopted = hi >= 0 and worst >= -0.005
        asks = "an interval reaching 0 and no cell lower by more than 0.5 points"
    else:
        auc_drop = max(auc[rows][c] - auc[pairs][c] for c in auc[rows])
        later = max(converged[pairs][c] - converged[rows][c] for c in converged[rows])
        adopted = lo >= -margin and worst >= -0.005 and auc_drop <= 0.02 and later <= 100
        said += (
            f" Per cell, `auc` at most {auc_drop:.4f} lower and `converged` at most "
            f"{later:.0f} episodes later."
        )
        asks = (
            f"the interval's lower end at or above {-100 * margin:+.2f} points, no cell lower "
            "by more than 0.5 points, `auc` at most 0.02 lower and `converged` at most 100 "
            "episodes later per cell"
        )
    lines += [
        "",
        f"{said} The rule (`rule.md`) asks for {asks}: "
        f"**{'adopted' if adopted else 'not adopted'}**.",
    ]
    if spread:
        point, lo, hi = difference(rows, spread)
        lines += [
            "",
            f"Outside the rule, the rows on other seeds (`{spread}`), {spread} − {rows}: "
            f"{100 * point:+.3f} points, 95% interval [{100 * lo:+.3f}, {100 * hi:+.3f}]; "
            f"failures {failures(rows)} ({rows}), {failures(pairs)} ({pairs}), "
            f"{failures(spread)} ({spread}) of {1000 * models:,} held-out lane changes each.",
        ]
    return "\n".join(lines)


BLOCKS = {
    "pairs-s20": functools.partial(
        pairs_table, PAIRS_STUDY_S20, "rows20", "pairs20", 0.0005, "rows20b"
    ),
}
