"""Held-out lane changes per cell of a study: success with its interval, failures and
collisions with their one-sided bounds, the share inside every norm."""

from __future__ import annotations

from pathlib import Path

from benchmarks.tables.common import BENCHMARKS, duration_rule, load
from jaxlc.report.report import EVERY_STEP

DEFAULT_STUDY = BENCHMARKS / "study_symmetric_cpu_s3"  # today's default, three seeds per cell
TEN_SEEDS = BENCHMARKS / "study_default_cpu_s10"  # today's default, ten seeds per cell
PAPER_STUDY = BENCHMARKS / "study_paper_gpu_s10"  # configs/paper.toml, ten seeds per cell


def heldout_cells(study: Path = DEFAULT_STUDY) -> str:
    """Per cell of a study (the default's unless given): held-out success (the seeds' range
    of Clopper-Pearson intervals under 5 seeds), failures and collisions with their one-sided
    95% bounds, share inside every norm."""
    lines = [
        "| cell | seeds | lane changes | success | 95% interval | failures (bound) | collisions "
        "(bound) | inside every norm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    doc = load(study, "heldout.json")
    for c in doc.cells:
        lines.append(
            f"| {c.label} | {c.seeds} | {c.lane_changes:,} | {100 * c.success_mean:.2f}% | "
            f"[{100 * c.success_lo:.2f}, {100 * c.success_hi:.2f}]% | {c.failures} "
            f"(< {100 * c.failure_bound:.2f}%) | {c.collisions} "
            f"(< {100 * c.collision_bound:.2f}%) | {100 * c.norm_all:.1f}% |"
        )
    counted = doc.conflicts_counted or EVERY_STEP
    return "\n".join(
        [*lines, "", f"Headway and time-to-collision counted {counted}. {duration_rule(doc)}"]
    )


BLOCKS = {
    "heldout-cells": heldout_cells,
    "heldout-cells-s10": lambda: heldout_cells(TEN_SEEDS),
    "paper-cells": lambda: heldout_cells(PAPER_STUDY),
}
