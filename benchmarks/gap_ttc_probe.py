"""Gap acceptance by time-to-collision: how ``env.gap_min_ttc`` changes the lane changes made,
their collisions and their norms, for the final checkpoints of a run (no retraining).

    python benchmarks/gap_ttc_probe.py runs/s0 --ttc 0 3 4 5 --lane-changes 2000

For each value: the share of held-out cases that perform a lane change, and per model the
held-out outcomes (``jaxlc.evaluation.heldout``) on the same key stream. Writes
``OUT/probe.csv`` and prints it; OUT defaults to ``benchmarks/gap_ttc_probe/``.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import time
from pathlib import Path

from jaxlc.evaluate import final_checkpoints, load_rows
from jaxlc.evaluation import heldout
from jaxlc.evaluation.cases import evaluate_policies, keys_for_lane_changes
from jaxlc.study import machine

FIELDS = (
    "gap_min_ttc",
    "label",
    "seed",
    "cases",
    "lane_changes",
    "performed_share",
    "success",
    "collision",
    "out_of_bounds",
    "timeout",
    "norm_all",
    "norm_min_ttc_s",
    "norm_min_thw_s",
)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--ttc", type=float, nargs="+", default=[0.0, 3.0, 4.0, 5.0])
    ap.add_argument("--lane-changes", type=int, default=2000)
    ap.add_argument("--out", type=Path, default=Path(__file__).with_suffix(""))
    args = ap.parse_args()
    base, actors, metas = load_rows(args.run_dir, final_checkpoints(args.run_dir))
    rows = []
    for ttc in args.ttc:
        t0 = time.time()
        cfg = dataclasses.replace(base, env=dataclasses.replace(base.env, gap_min_ttc=ttc))
        keys = keys_for_lane_changes(cfg, args.lane_changes, seed=0)
        out, _, info = evaluate_policies(
            cfg, [None, *actors], [1] + [m["k"] for m in metas[1:]], keys=keys, traced=0
        )
        for p, meta in enumerate(metas):
            r = heldout.model_row(out, info, p, cfg.env.dt)
            rows.append(
                {
                    "gap_min_ttc": ttc,
                    "label": meta["label"],
                    "seed": meta["seed"],
                    "cases": len(keys),
                    "performed_share": r["lane_changes"] / len(keys),
                    **{k: r[k] for k in FIELDS if k in r},
                }
            )
        print(f"gap_min_ttc {ttc}: {time.time() - t0:.0f} s", flush=True)
    args.out.mkdir(parents=True, exist_ok=True)
    with open(args.out / "probe.csv", "w", newline="") as f:
        w = csv.DictWriter(f, FIELDS, extrasaction="ignore", lineterminator="\n")
        w.writeheader()
        w.writerows(rows)
    print((args.out / "probe.csv").read_text())
    print(f"matmul peak {machine.matmul_peak_gflops():.0f} GFLOP/s")


if __name__ == "__main__":
    main()
