"""One config value, several settings, the final checkpoints of a run (no retraining): how the
value changes the held-out lane changes, their collisions and their norms.

    python -m benchmarks.probe runs/s0 --key env.gap_min_ttc --values 0 3 4 5 \
        --lane-changes 2000 --out benchmarks/gap_ttc_probe
    python -m benchmarks.probe runs/s3 --key ddpg.symmetric_actor --values false true \
        --out benchmarks/symmetric_probe

For each value (TOML syntax; validated as the config is): the share of held-out cases that
perform a lane change, and per model the held-out outcomes (``jaxlc.evaluation.heldout``) on
the same key stream. Writes ``OUT/probe.csv`` (its first column is named for the key) and
prints it.
"""

from __future__ import annotations

import argparse
import dataclasses
import time
from pathlib import Path

from benchmarks import write_csv
from jaxlc import config
from jaxlc.evaluation import heldout
from jaxlc.evaluation.cases import cases_for_lane_changes, evaluate_policies
from jaxlc.evaluation.protocol import final_checkpoints, load_rows
from jaxlc.study import machine

FIELDS = tuple(
    "label seed cases lane_changes performed_share success collision out_of_bounds timeout "
    "norm_all norm_min_ttc_s norm_min_thw_s".split()
)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--key", required=True, help="table.key, e.g. env.gap_min_ttc")
    ap.add_argument("--values", nargs="+", required=True, help="TOML values, e.g. 0 3 4 5")
    ap.add_argument("--lane-changes", type=int, default=2000)
    ap.add_argument("--out", type=Path, required=True)
    args = ap.parse_args()
    base, actors, metas = load_rows(args.run_dir, final_checkpoints(args.run_dir))
    rows = []
    for text in args.values:
        t0 = time.time()
        table, name, value = config.parse_override(f"{args.key}={text}")
        data = dataclasses.asdict(base)
        data.setdefault(table, {})[name] = value
        cfg = config.from_dict(data)  # validated: a bad key or value names itself
        keys, started = cases_for_lane_changes(cfg, args.lane_changes, seed=0)
        out, _, info = evaluate_policies(
            cfg, [None, *actors], [1] + [m["k"] for m in metas[1:]], started=started, traced=0
        )
        for p, meta in enumerate(metas):
            r = heldout.model_row(out, info, p, cfg.env.dt)
            rows.append(
                {
                    name: text,
                    "label": meta["label"],
                    "seed": meta["seed"],
                    "cases": len(keys),
                    "performed_share": r["lane_changes"] / len(keys),
                    **{k: r[k] for k in FIELDS if k in r},
                }
            )
        print(f"{args.key} = {text}: {time.time() - t0:.0f} s", flush=True)
    write_csv(args.out / "probe.csv", rows, (name, *FIELDS))
    print((args.out / "probe.csv").read_text())
    print(f"matmul peak {machine.matmul_peak_gflops():.0f} GFLOP/s")


if __name__ == "__main__":
    main()
