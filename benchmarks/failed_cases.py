"""Every held-out lane change that failed, one row each, from a run's evaluation.

``python -m jaxlc.evaluate`` keeps the per-case outcomes in ``eval/heldout_cases.npz``, a file
too large to commit for every study; this writes the failed cases alone (out of bounds,
collision or timeout; cases with no lane change are not failures) with where the ego ended,
so that what a study says of its failures can be recomputed from a small committed file.

Usage: ``python -m benchmarks.failed_cases RUN/eval``; writes ``RUN/eval/failed_cases.csv``.
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np

from benchmarks import write_csv
from jaxlc.sim.reward import REASONS

FAILED = ("out_of_bounds", "collision", "timeout")
FIELDS = ("label", "seed", "case", "side", "reason", "rl_steps", "final_offset_m",
          "final_psi_rad", "final_omega_rad_s")  # fmt: skip


def failed_cases(eval_dir: Path) -> list[dict]:
    """The failed rows of ``heldout_cases.npz``, labelled by ``heldout.csv`` (same row order:
    the baseline first, then each model)."""
    d = np.load(eval_dir / "heldout_cases.npz")
    with open(eval_dir / "heldout.csv", newline="") as f:
        policies = list(csv.DictReader(f))
    cases = np.flatnonzero(d["performed"])  # (lane changes,) indices of the drawn cases
    rows = []
    for i, policy in enumerate(policies):
        for c in cases:
            reason = REASONS[int(d["reason"][i, c])]
            if reason in FAILED:
                rows.append(
                    {
                        "label": policy["label"],
                        "seed": policy["seed"],
                        "case": int(d["case"][c]),
                        "side": int(d["side"][c]),
                        "reason": reason,
                        "rl_steps": int(d["steps"][i, c]),
                        "final_offset_m": round(float(d["final_offset"][i, c]), 4),
                        "final_psi_rad": round(float(d["final_psi"][i, c]), 5),
                        "final_omega_rad_s": round(float(d["final_omega"][i, c]), 5),
                    }
                )
    return rows


def main(argv: list[str] | None = None) -> list[dict]:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("eval_dir", type=Path, help="RUN/eval, as python -m jaxlc.evaluate wrote it")
    eval_dir = ap.parse_args(argv).eval_dir
    rows = failed_cases(eval_dir)
    write_csv(eval_dir / "failed_cases.csv", rows, FIELDS)
    print(f"{len(rows)} failed lane changes -> {eval_dir / 'failed_cases.csv'}")
    return rows


if __name__ == "__main__":
    main()
