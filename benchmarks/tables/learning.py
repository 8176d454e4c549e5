"""How the learning was made reliable: the GPU study of eight seeds per setting, the
"every seed learns" targets and its per-cell table."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from benchmarks import study_summary
from benchmarks.tables.common import BENCHMARKS, csv_rows
from benchmarks.tables.speed import bench
from jaxlc.evaluation import stats
from jaxlc.evaluation.results import Row
from jaxlc.paper.grid import is_best

# The GPU study's settings (its folders under study_gpu_8seeds/), against its first row.
GPU_STUDY = BENCHMARKS / "study_gpu_8seeds"
GPU_SETTINGS = (
    ("default", "`ddpg.huber_delta=0 ddpg.mirror=false` (the morning's default)"),
    ("tterm", "… `env.terminal_timeout=true`"),
    ("rs01", "… `env.reward_scale=0.1`"),
    ("ups2", "… `ddpg.updates_per_step=2`"),
    ("mirror", "… `ddpg.mirror=true`"),
    ("mirror_ups2", "… `ddpg.mirror=true ddpg.updates_per_step=2`"),
    ("huber10", "… `ddpg.huber_delta=10`"),
    (
        "mirror_huber",
        "… `ddpg.huber_delta=10 ddpg.mirror=true` (the default before the odd "
        "actor and the gap test)",
    ),
)
EVERY_CHECKPOINT = BENCHMARKS / "study_default_cpu_s3"  # every checkpoint evaluated, 3 seeds


def study_cells(eval_csv: Path) -> str:
    """``benchmarks/study_summary.py`` on a study's committed ``eval.csv``: per cell the
    success at the last checkpoint over seeds, the best checkpoint and the drop to the last,
    the lane changes' duration, peak lateral acceleration and overshoot."""
    return study_summary.summary(study_summary.load(eval_csv)).rstrip("\n")


def _final_success(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(success, seed)`` of every model at its last evaluated checkpoint, ``(models,)``."""
    rows = [r for r in csv_rows(folder / "eval.csv", Row) if r.model is not None]
    last = max(r.episode for r in rows)
    final = [r for r in rows if r.episode == last]
    return np.array([r.success_rate for r in final]), np.array([r.seed for r in final])


def _studies_at(success: np.ndarray, seeds: np.ndarray, level: float = 0.99) -> tuple[int, int]:
    """Read as one-seed studies (the models of one seed each): ``(how many have a model at
    >= level, how many studies)``."""
    best = [success[seeds == s].max() for s in np.unique(seeds)]
    return sum(b >= level for b in best), len(best)


def moved_table() -> str:
    """What moved the learning: per GPU setting its sweep's wall time, the mean evaluated
    success of its 72 models and the difference from the first row with its 95% interval
    (``jaxlc.evaluation.stats.difference``), the cells whose own difference interval
    (``compare.csv``) lies above / below zero, and the models and one-seed studies at >= 99%."""

    def signed(x: float) -> str:
        return f"{100 * x:+.1f}".replace("-", "−")

    base, _ = _final_success(GPU_STUDY / "default")
    walls = (GPU_STUDY / "walls.txt").read_text()  # each sweep.log's closing line
    compare = csv_rows(GPU_STUDY / "compare.csv")  # python -m jaxlc.evaluate --compare, per setting
    lines = [
        f"| setting | sweep wall | success at 5000, mean of {base.size} | difference [95% CI] | "
        "cells up / down | models ≥ 99% | one-seed studies with a ≥ 99% model |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, label in GPU_SETTINGS:
        folder = GPU_STUDY / name
        wall = re.search(rf"^{name}: Wall time (\d+) s", walls, re.M)[1]
        success, seeds = _final_success(folder)
        studies = "{} of {}".format(*_studies_at(success, seeds))
        diff = cells = "–"
        if name != "default":
            d, lo, hi = stats.difference(base, success)
            diff = f"{signed(d)} [{signed(lo)}, {signed(hi)}]"
            rows = [r for r in compare if r["setting"] == name]
            up = sum(float(r["diff_lo"]) > 0 for r in rows)
            cells = f"{up} / {sum(float(r['diff_hi']) < 0 for r in rows)}"
        lines.append(
            f"| {label} | {wall} s | {100 * success.mean():.1f}% | {diff} | {cells} | "
            f"{int(np.sum(success >= 0.99))} | {studies} |"
        )
    return "\n".join(lines)


def _largest_drop(eval_csv: Path) -> tuple[int, float]:
    """``(last episode, largest drop)``: how far a cell's mean success over seeds at the last
    checkpoint lies below its best checkpoint's, the most of any cell."""
    by_cell: dict[str, dict[int, list[float]]] = {}
    for r in csv_rows(eval_csv, Row):
        if r.model is not None:
            by_cell.setdefault(r.label, {}).setdefault(r.episode, []).append(r.success_rate)
    last = max(max(eps) for eps in by_cell.values())
    drop = max(
        max(np.mean(v) for v in eps.values()) - np.mean(eps[last]) for eps in by_cell.values()
    )
    return last, float(drop)


def targets_table() -> str:
    """The "every seed learns" targets against the GPU study of eight seeds (its eval.csv and
    summary.json), the CPU study that evaluated every checkpoint, and both time-to-solution
    runs; each verdict follows from the figures beside it."""
    gpu = GPU_STUDY / "mirror_huber"
    rows = [r for r in csv_rows(gpu / "eval.csv", Row) if r.model is not None and r.episode == 5000]
    cells: dict[str, list[Row]] = {}
    for r in rows:
        cells.setdefault(r.label, []).append(r)
    mean = {c: np.mean([r.success_rate for r in rs]) for c, rs in cells.items()}
    k = {c: rs[0].k for c, rs in cells.items()}
    four = next(c for c, rs in cells.items() if is_best(rs[0]))
    d = stats.describe(np.array([r.success_rate for r in cells[four]]))
    small = [mean[c] for c in cells if k[c] != 4]
    big = [mean[c] for c in cells if k[c] == 4]
    cases = sum(r.performed for r in rows)
    collided = sum(r.collision for r in rows)
    ends = [
        m["ends_last"]["collision"]
        for m in json.loads((gpu / "summary.json").read_text())["models"]
    ]
    studies, n_studies = _studies_at(*_final_success(gpu))
    last_ep, drop = _largest_drop(EVERY_CHECKPOINT / "eval" / "eval.csv")
    durations = [r.duration_s for r in rows if r.duration_s is not None]
    (now,) = bench("time_to_solution.csv")
    (then,) = csv_rows(EVERY_CHECKPOINT / "time_to_solution.csv")
    scaled = float(now["wall_s"]) * float(now["matmul_peak_gflops"]) / 200

    def met(ok: bool) -> str:
        return "met" if ok else "not met"

    dur = [np.mean([r.duration_s for r in rs if r.duration_s is not None]) for rs in cells.values()]
    lines = [
        '| target ("every seed learns") | measured | |',
        "|---|---|---|",
        f"| ④ mean evaluated success ≥ 95% over 8 seeds | {100 * d['mean']:.1f}% "
        f"[{100 * d['mean_lo']:.1f}, {100 * d['mean_hi']:.1f}] (GPU) | {met(d['mean'] >= 0.95)} |",
        f"| every k ≤ 2 cell ≥ 90%; every k = 4 cell ≥ 75% | k ≤ 2: {100 * min(small):.1f}–"
        f"{100 * max(small):.1f}%; k = 4: {100 * min(big):.1f}–{100 * max(big):.1f}% (GPU) | "
        f"{met(min(small) >= 0.9 and min(big) >= 0.75)} |",
        f"| no collisions | evaluation: {collided} in {cases:,} model-cases (GPU); training (noise "
        f"on): {sum(ends)} collisions in the last 100 episodes of the {len(ends)} models, "
        f"{sum(e > 0 for e in ends)} models with one or more ([`summary.json`]"
        f"(../benchmarks/study_gpu_8seeds/mirror_huber/summary.json)) | "
        f"{met(collided == 0)} in evaluation, {met(sum(ends) == 0)} in training |",
        f"| ≥ 7 of 8 one-seed studies with a model at ≥ 99% | {studies} of {n_studies} (GPU) | "
        f"{met(studies >= 7)} |",
        f"| each cell's mean at {last_ep} within 5 points of its best checkpoint | largest drop "
        f"{100 * drop:.1f} points (CPU, 3 seeds, every checkpoint evaluated: "
        f"[`study_default_cpu_s3/`](../benchmarks/study_default_cpu_s3/)) | "
        f"{met(drop <= 0.05)} (CPU) |",
        f"| lane change 3–8 s | per cell {min(dur):.1f}–{max(dur):.1f} s (GPU; per model "
        f"{min(durations):.1f}–{max(durations):.1f} s) | "
        f"{met(3 <= min(durations) and max(durations) <= 8)} |",
        f"| time to solution ≤ 4 min on a 200 GFLOP/s CPU | {float(now['wall_s']):.1f} s at "
        f"{float(now['matmul_peak_gflops']):.0f} GFLOP/s ({now['date']}), ≈ {scaled:.0f} s scaled "
        f"to 200 GFLOP/s by the peaks' ratio; {float(then['wall_s']):.1f} s at "
        f"{float(then['matmul_peak_gflops']):.0f} GFLOP/s ({then['date']}, that day's default) | "
        f"{met(scaled <= 240)} by today's run scaled; "
        f"{met(float(then['wall_s']) <= 240 and float(then['matmul_peak_gflops']) <= 200)} on the "
        "slower VM |",
        "| time to solution ≤ 10 s on a GPU | not measured | open |",
    ]
    return "\n".join(lines)


BLOCKS = {
    "gpu8-cells": lambda: study_cells(GPU_STUDY / "mirror_huber" / "eval.csv"),
    "moved": moved_table,
    "targets": targets_table,
}
