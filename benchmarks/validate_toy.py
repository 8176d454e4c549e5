"""The IS estimator's toy check: a failure probability known in closed form, 100 repeats.

    python benchmarks/scripts/validate_toy.py --repeats 100 --samples 20000

A toy failure is at least ``TOY_K`` = 9 of ``TOY_D`` = 100 events of probability 0.01 firing
(``jaxlc.evaluation.rare``; truth 8.39e-7, the binomial tail). Each repeat fits its own
proposal by the cross-entropy method on pilot batches from a key of its own, then estimates
from ``--samples`` samples; counts how many 95% intervals cover the truth and how many mean
weights are 1 within their interval. Writes ``OUT/toy.json``.
"""

from __future__ import annotations

import argparse
import datetime
import json
import platform
import time
from pathlib import Path

import jax
import numpy as np

from jaxlc.evaluation import rare
from jaxlc.study import machine


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=100)
    ap.add_argument("--samples", type=int, default=20000)
    here = Path(__file__).resolve().parent / "results"
    ap.add_argument("--out", type=Path, default=here)
    args = ap.parse_args()
    t0 = time.perf_counter()
    runs = [
        rare.toy_estimate(jax.random.PRNGKey(1000 + i), args.samples) for i in range(args.repeats)
    ]
    truth = rare.toy_truth()
    covered = sum(r["lo"] <= truth <= r["hi"] for r in runs)
    weight_ok = sum(r["mean_weight_lo"] <= 1.0 <= r["mean_weight_hi"] for r in runs)
    result = {
        "truth": truth,
        "repeats": args.repeats,
        "samples": args.samples,
        "covered": int(covered),
        "mean_weight_covers_1": int(weight_ok),
        "mean_estimate": float(np.mean([r["estimate"] for r in runs])),
        "mean_rel_halfwidth": float(np.mean([r["rel_halfwidth"] for r in runs])),
        "q": [r["q"] for r in runs],
        "seconds": round(time.perf_counter() - t0, 1),
        "matmul_peak_gflops": round(machine.matmul_peak_gflops()),
        "machine": platform.processor() or platform.machine(),
        "date": datetime.date.today().isoformat(),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "toy.json").write_text(json.dumps(result, indent=1) + "\n")
    print({k: v for k, v in result.items() if k != "q"})


if __name__ == "__main__":
    main()
