"""Per-cell table of held-out lane changes in several traffics, from committed files.

Each ``DIR/TAG/heldout.json`` (``python -m jaxlc.evaluate RUN --heldout-only --traffic ...
--tag TAG`` writes ``RUN/eval/heldout_TAG/``; the training traffic's is ``RUN/eval/``) gives
one column group: pooled success, collisions, the lane changes that met a cut-in and a braking
event around the ego, and the share inside every norm (mean over seeds).

    python -m benchmarks.traffic_table benchmarks/study_hazards_cpu_s3/default \
        paper hazards hazards_x2
    python -m benchmarks.traffic_table benchmarks/study_hazards_cpu_s3/default \
        paper hazards --against benchmarks/study_hazards_cpu_s3/reactive
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np


def cells(path: Path) -> dict[str, dict]:
    """Label -> pooled counts of one ``heldout.json``'s models, by grid cell."""
    out: dict[str, dict] = {}
    for r in json.loads(path.read_text())["rows"]:
        if r["model"] is None:
            continue
        c = out.setdefault(
            r["label"], {"n": 0, "ok": 0, "hits": 0, "cut": 0, "brake": 0, "norm": []}
        )
        c["n"] += r["lane_changes"]
        c["ok"] += r["success"]
        c["hits"] += r["collision"]
        c["cut"] += r.get("met_cut_in", 0)
        c["brake"] += r.get("met_braking", 0)
        c["norm"].append(r["norm_all"])
    return out


def table(root: Path, tags: list[str]) -> str:
    docs = {t: cells(root / t / "heldout.json") for t in tags}
    head = "| cell | " + " | ".join(
        f"{t}: success | coll. | met cut-in | met braking | all norms" for t in tags
    )
    lines = [head + " |", "|---|" + "---|---|---|---|---|" * len(tags)]
    for label in docs[tags[0]]:
        parts = []
        for t in tags:
            c = docs[t][label]
            parts.append(
                f"{100 * c['ok'] / c['n']:.2f}% of {c['n']:,} | {c['hits']} | {c['cut']} | "
                f"{c['brake']} | {100 * sum(c['norm']) / len(c['norm']):.1f}%"
            )
        lines.append(f"| {label} | " + " | ".join(parts) + " |")
    return "\n".join(lines)


def difference(a: Path, b: Path, resamples: int = 10_000) -> tuple[float, float, float, float]:
    """``(point, lo, hi, worst)``: held-out success pooled over the models of ``b`` minus that
    of ``a`` (two ``heldout.json``), with a 95% bootstrap interval (seeds resampled within
    cells, generator seed 0, as the reflection pairs' rule), and the largest drop in a cell."""
    rng = np.random.default_rng(0)

    def per_seed(path: Path) -> dict[str, np.ndarray]:
        out: dict[str, list[float]] = {}
        for r in json.loads(path.read_text())["rows"]:
            if r["model"] is not None:
                out.setdefault(r["label"], []).append(r["success"] / r["lane_changes"])
        return {k: np.asarray(v) for k, v in out.items()}

    sa, sb = per_seed(a), per_seed(b)

    def pooled(cells: dict[str, np.ndarray], resample: bool) -> float:
        pick = (lambda v: rng.choice(v, v.size)) if resample else (lambda v: v)
        return float(np.mean([pick(v).mean() for v in cells.values()]))

    point = pooled(sb, False) - pooled(sa, False)
    boot = [pooled(sb, True) - pooled(sa, True) for _ in range(resamples)]
    lo, hi = np.percentile(boot, [2.5, 97.5])
    worst = min(sb[c].mean() - sa[c].mean() for c in sa)
    return point, float(lo), float(hi), float(worst)


def main(argv: list[str] | None = None) -> str:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("root", type=Path)
    ap.add_argument("tags", nargs="+")
    ap.add_argument(
        "--against",
        type=Path,
        help="another study's root: B - A of each tag's pooled held-out success (A: this one)",
    )
    args = ap.parse_args(argv)
    text = table(args.root, args.tags)
    for tag in args.tags if args.against else ():
        point, lo, hi, worst = difference(
            args.root / tag / "heldout.json", args.against / tag / "heldout.json"
        )
        text += (
            f"\n\n{tag}: {args.against.name} - {args.root.name}, pooled held-out success "
            f"{100 * point:+.3f} points, 95% interval [{100 * lo:+.3f}, {100 * hi:+.3f}]; "
            f"the largest drop in a cell {100 * -worst:.2f} points."
        )
    print(text)
    return text


if __name__ == "__main__":
    main()
