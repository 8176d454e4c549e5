"""RL transitions per DDPG update, from a run's ``metrics/steps.npz`` (per scan step and
model: ``transitions``, ``updates``), over the phases of each model's run: its first 10% of
scan steps, the next 40%, the second half, and the whole run.

    python benchmarks/scripts/update_ratio.py runs/s3 --keep benchmarks/study_symmetric_cpu_s3

``--keep DIR`` writes ``DIR/update_ratio.csv`` (one row per model) and ``DIR/metrics/
step_counts.npz`` (the two count arrays, compressed: the evidence the CSV is computed from,
without the run's losses).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from csvfile import write_csv

PHASES = (("first_10pct", 0.0, 0.1), ("next_40pct", 0.1, 0.5), ("second_half", 0.5, 1.0))


def _ratio(t: np.ndarray, u: np.ndarray) -> float:
    return float(t.sum() / u.sum()) if u.sum() else float("nan")  # nan: no update in the phase


def ratios(transitions: np.ndarray, updates: np.ndarray) -> list[dict[str, float]]:
    """Per model (columns of the ``(steps, models)`` counts): transitions per update in each
    phase of the scan steps that model ran (up to its last step with a transition)."""
    rows = []
    for m in range(transitions.shape[1]):
        t, u = transitions[:, m].astype(np.int64), updates[:, m].astype(np.int64)
        n = int(np.nonzero(t)[0].max()) + 1
        row = {"model": m, "scan_steps": n, "all": _ratio(t[:n], u[:n])}
        for name, lo, hi in PHASES:
            a, b = int(lo * n), int(hi * n)
            row[name] = _ratio(t[a:b], u[a:b])
        rows.append(row)
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("source", type=Path, help="a run directory, or a folder --keep wrote")
    ap.add_argument("--keep", type=Path, default=None)
    args = ap.parse_args(argv)
    metrics = args.source / "metrics"
    path = (
        metrics / "steps.npz" if (metrics / "steps.npz").exists() else metrics / "step_counts.npz"
    )
    with np.load(path) as d:
        transitions, updates = d["transitions"], d["updates"]
    labels = [m["label"] for m in json.loads((args.source / "summary.json").read_text())["models"]]
    rows = [{"label": labels[r["model"]], **r} for r in ratios(transitions, updates)]
    for key in ("first_10pct", "next_40pct", "second_half", "all"):
        v = [r[key] for r in rows]
        print(
            f"{key:12} transitions per update: mean {np.nanmean(v):.2f}, "
            f"{np.nanmin(v):.2f}-{np.nanmax(v):.2f}"
        )
    if args.keep is not None:
        (args.keep / "metrics").mkdir(parents=True, exist_ok=True)
        np.savez_compressed(
            args.keep / "metrics" / "step_counts.npz", transitions=transitions, updates=updates
        )
        write_csv(args.keep / "update_ratio.csv", rows)
    return 0


if __name__ == "__main__":
    sys.exit(main())
