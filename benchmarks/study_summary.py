"""The per-cell figures of a multi-seed study, recomputed from its ``eval/eval.csv`` alone
(the file committed beside each study under ``benchmarks/``):

- per cell: mean evaluated success at the last checkpoint with its 95% bootstrap interval
  over seeds (``jaxlc.evaluation.stats``), the best checkpoint's mean and the drop from it to
  the last (a late collapse), and the mean lane-change duration, peak lateral acceleration and
  overshoot of the successful cases; the scripted controller beside them;
- read as one-seed studies (the nine cells of one seed index each): how many have a model
  at >= 99% at the last checkpoint.

    python -m benchmarks.study_summary benchmarks/study_default_s3/eval.csv
"""

from __future__ import annotations

import argparse
import csv
from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from jaxlc.evaluation import stats
from jaxlc.paper.grid import LABELS as PAPER_LABELS


def _num(text: str) -> float:
    return float(text) if text not in ("", None) else float("nan")


def load(path: Path) -> list[dict[str, object]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def summary(rows: list[dict[str, object]], solved: float = 0.99) -> str:
    scripted = [r for r in rows if r["model"] == ""]
    models = [r for r in rows if r["model"] != ""]
    last_ep = max(int(r["episode"]) for r in models)
    by_cell: dict[tuple[int, int], dict[int, list[dict]]] = defaultdict(lambda: defaultdict(list))
    for r in models:
        by_cell[(int(r["k"]), int(r["memory"]))][int(r["episode"])].append(r)
    lines = [
        f"| cell | seeds | success at {last_ep}: mean [95% CI] | best checkpoint mean "
        "(episode) | drop to the last | lane change s | peak lateral acc. m/s² | overshoot m |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in scripted[:1]:
        lines.append(
            f"| scripted controller | – | {_num(r['success_rate']):.1%} | – | – | "
            f"{_num(r['duration_s']):.1f} | {_num(r['peak_lat_acc']):.2f} | "
            f"{_num(r['overshoot_m']):.2f} |"
        )
    for key in sorted(by_cell):  # (k, memory)
        eps = by_cell[key]
        final = np.array([_num(r["success_rate"]) for r in eps[last_ep]])
        d = stats.describe(final)
        means = {e: np.mean([_num(r["success_rate"]) for r in rs]) for e, rs in eps.items()}
        best_ep = max(means, key=lambda e: (means[e], e))
        measure = {
            m: np.nanmean([_num(r[m]) for r in eps[last_ep]])
            for m in ("duration_s", "peak_lat_acc", "overshoot_m")
        }
        tag = PAPER_LABELS.get(key, "")
        lines.append(
            f"| {tag} k={key[0]} D={key[1]} | {len(final)} | {final.mean():.1%} "
            f"[{d['mean_lo']:.1%}, {d['mean_hi']:.1%}] | {means[best_ep]:.1%} ({best_ep}) | "
            f"{means[best_ep] - final.mean():.1%} | {measure['duration_s']:.1f} | "
            f"{measure['peak_lat_acc']:.2f} | {measure['overshoot_m']:.2f} |"
        )
    seeds: dict[int, float] = defaultdict(float)
    for r in models:
        if int(r["episode"]) == last_ep:
            seeds[int(r["seed"])] = max(seeds[int(r["seed"])], _num(r["success_rate"]))
    hits = sum(v >= solved for v in seeds.values())
    lines += [
        "",
        f"Read as {len(seeds)} one-seed studies: {hits} of {len(seeds)} have a model at "
        f">= {solved:.0%} at episode {last_ep} (best model per seed: "
        + ", ".join(f"{seeds[s]:.1%}" for s in sorted(seeds))
        + ").",
    ]
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> str:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("eval_csv", type=Path, help="a run's eval/eval.csv")
    args = ap.parse_args(argv)
    text = summary(load(args.eval_csv))
    print(text)
    return text


if __name__ == "__main__":
    main()
