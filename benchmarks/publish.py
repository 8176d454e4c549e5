"""Published tables written from committed evidence, never typed.

    python benchmarks/publish.py            # rewrite every block in README.md
    python benchmarks/publish.py --check    # exit 1 naming each block that differs

A block is the text of README.md between ``<!-- publish:NAME -->`` and ``<!-- /publish:NAME -->``;
``BLOCKS[NAME]`` writes it from the committed study folders under ``benchmarks/`` (each holds
the ``eval/`` files that ``python -m jaxlc.evaluate`` wrote). ``tests/test_publish.py`` runs the
check, so a table that no longer matches its evidence fails the suite.
"""

from __future__ import annotations

import argparse
import csv
import functools
import json
import re
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

from jaxlc import config

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"

# The studies the verdict rests on (configs/paper.toml's, configs/default.toml's).
PAPER_STUDY = ROOT / "benchmarks" / "study_paper_cpu_s1"
DEFAULT_STUDY = ROOT / "benchmarks" / "study_symmetric_cpu_s3"
# configs/roads.toml's study, with both probes of env.curvature (roads- and straight-trained).
ROADS_STUDY = ROOT / "benchmarks" / "study_roads_cpu_s3"

# What the paper shows for each claim (its text, section IV), keyed by the claim's tag.
PAPER_SHOWS = {
    "(c)": "Fig. 3a: ① and ② show a better converging trend than ③",
    "(a, b)": "Fig. 3b: among ①④⑤, ④ converges fast and has the best performance",
    "(b)": "Fig. 3c: among ②⑥⑦, ⑦ shows the best performance",
    "(a)": "Figs. 3d, 4a: ④ converges faster than ⑦; its manoeuvring steps rise earlier",
    "(d)": "Fig. 6, §IV-C: ④ completes 100% of the lane changes of 100 test cases",
}
# Measures counted in episodes (written whole, "ep"); the others are written to 3 figures.
_EPISODES = {"converged", "success95", "steps_rise"}


@functools.cache
def _load(study: Path, name: str) -> dict[str, Any]:
    return json.loads((study / "eval" / name).read_text())


def _tag(claim: str) -> str:
    """``"(a, b) ④ converges …"`` -> ``"(a, b)"``."""
    return claim[: claim.index(")") + 1]


def _seeds(study: Path) -> str:
    n = len({m["seed"] for m in _load(study, "convergence.json")["models"]})
    return f"{n} seed{'s' if n > 1 else ''} per cell"


def _comparisons(study: Path, claim: dict[str, str]) -> str:
    """A claim's comparisons in a study on the measures it is decided by: each side's mean over
    seeds, and P(x better than y) with its interval from 2 seeds on."""
    parts = []
    measures = claim["measures"].split(", ")
    for c in _load(study, "convergence.json")["comparisons"]:
        if c["claim"] != claim["claim"] or c["measure"] not in measures:
            continue
        episodes = c["measure"] in _EPISODES
        fmt = "{:.0f}" if episodes else "{:.3g}"
        x, y = (("never" if v is None else fmt.format(v)) for v in (c["x_mean"], c["y_mean"]))
        text = f"{c['measure']}: {c['x']} {x} vs {c['y']} {y}{' ep' if episodes else ''}"
        if c["seeds"] > 1:
            text += f", P = {c['p']:.2f} [{c['p_lo']:.2f}, {c['p_hi']:.2f}]"
        parts.append(text)
    return "; ".join(parts)


def _claim_d(study: Path) -> tuple[str, str]:
    doc = _load(study, "heldout.json")
    cell = next(c for c in doc["cells"] if c["label"].startswith("④"))
    text = (
        f"{cell['failures']} failures ({cell['collisions']} collisions) in "
        f"{cell['lane_changes']:,} held-out lane changes; fails in < "
        f"{100 * cell['failure_bound']:.2f}% (95%)"
    )
    return text, doc["claim_d"]["verdict"]


def verdict_table() -> str:
    """Each paper claim: what the paper shows, paper.toml's and default.toml's figures here,
    and both verdicts (``jaxlc.evaluation.convergence``, ``jaxlc.evaluation.heldout``)."""
    lines = [
        f"| claim | the paper shows | `paper.toml` here ({_seeds(PAPER_STUDY)}) | "
        f"`default.toml` here ({_seeds(DEFAULT_STUDY)}) | verdict (paper.toml; default.toml) |",
        "|---|---|---|---|---|",
    ]
    paper_claims = {c["claim"]: c for c in _load(PAPER_STUDY, "convergence.json")["claims"]}
    for claim in _load(DEFAULT_STUDY, "convergence.json")["claims"]:
        text = claim["claim"]
        lines.append(
            f"| {text} | {PAPER_SHOWS[_tag(text)]} | {_comparisons(PAPER_STUDY, claim)} | "
            f"{_comparisons(DEFAULT_STUDY, claim)} | {paper_claims[text]['verdict']}; "
            f"{claim['verdict']} |"
        )
    (p_text, p_verdict), (d_text, d_verdict) = _claim_d(PAPER_STUDY), _claim_d(DEFAULT_STUDY)
    claim_d = _load(DEFAULT_STUDY, "heldout.json")["claim_d"]["claim"]
    lines.append(
        f"| {claim_d} | {PAPER_SHOWS['(d)']} | {p_text} | {d_text} | {p_verdict}; {d_verdict} |"
    )
    return "\n".join(lines)


def heldout_cells() -> str:
    """Per cell of the default study: held-out success (the seeds' range of Clopper-Pearson
    intervals under 5 seeds), failures, collisions and its bound, share inside every norm."""
    lines = [
        "| cell | seeds | lane changes | success | 95% interval | failures | collisions "
        "(bound) | inside every norm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for c in _load(DEFAULT_STUDY, "heldout.json")["cells"]:
        lines.append(
            f"| {c['label']} | {c['seeds']} | {c['lane_changes']:,} | "
            f"{100 * c['success_mean']:.2f}% | [{100 * c['success_lo']:.2f}, "
            f"{100 * c['success_hi']:.2f}]% | {c['failures']} | {c['collisions']} "
            f"(< {100 * c['collision_bound']:.2f}%) | {100 * c['norm_all']:.1f}% |"
        )
    return "\n".join(lines)


def _probe(path: Path) -> list[dict[str, str]]:
    with path.open() as f:
        return list(csv.DictReader(f))


def roads_table() -> str:
    """The roads study's policies (``configs/roads.toml``) and the straight-trained default's
    on the same held-out lane changes of straight and curved roads (``benchmarks/probe.py
    --key env.curvature``): per-model success range, failures by end, the scripted
    controller beside them."""
    lines = [
        "| road κ (1/m) | policies | models | lane changes per model | success per model "
        "(min – max) | failures: collision / out of bounds / timeout | scripted controller |",
        "|---|---|---|---|---|---|---|",
    ]

    def row(road: str, who: str, mine: list[dict[str, Any]]) -> str:
        models = [r for r in mine if r["seed"] not in ("", None)]
        (script,) = [r for r in mine if r["seed"] in ("", None)]
        n = int(models[0]["lane_changes"])
        succ = [int(r["success"]) / n for r in models]
        ends = [sum(int(r[k]) for r in models) for k in ("collision", "out_of_bounds", "timeout")]
        return (
            f"| {road} | {who} | {len(models)} | {n:,} | "
            f"{100 * min(succ):.1f}% – {100 * max(succ):.1f}% | "
            f"{' / '.join(f'{e:,}' for e in ends)} | "
            f"{int(script['success']):,} of {int(script['lane_changes']):,} |"
        )

    drawn = config.load(ROADS_STUDY / "config.toml").env.curvature
    road = f"drawn from [{drawn[0]:g}, {drawn[1]:g}]".replace("-", "−")
    lines.append(row(road, "`roads.toml`", _load(ROADS_STUDY, "heldout.json")["rows"]))
    probes = [("`roads.toml`", "probe_roads"), ("`default.toml` (straight)", "probe_straight")]
    rows = {name: _probe(ROADS_STUDY / name / "probe.csv") for _, name in probes}
    for kappa in dict.fromkeys(r["curvature"] for r in rows["probe_roads"]):
        for who, name in probes:
            road = "0" if float(kappa) == 0 else f"{float(kappa):+g}".replace("-", "−")
            lines.append(row(road, who, [r for r in rows[name] if r["curvature"] == kappa]))
    return "\n".join(lines)


BLOCKS: dict[str, Callable[[], str]] = {
    "verdict": verdict_table,
    "heldout-cells": heldout_cells,
    "roads": roads_table,
}
_BLOCK = re.compile(r"(<!-- publish:([\w-]+) -->\n)(.*?)(<!-- /publish:\2 -->)", re.S)


def render(text: str) -> tuple[str, list[str]]:
    """``(new text, names of the blocks that changed)``; an unknown block name is an error."""
    changed: list[str] = []

    def fill(m: re.Match[str]) -> str:
        name = m.group(2)
        if name not in BLOCKS:
            raise SystemExit(f"README block '{name}': no writer in benchmarks/publish.py")
        body = BLOCKS[name]() + "\n"
        if body != m.group(3):
            changed.append(name)
        return m.group(1) + body + m.group(4)

    return _BLOCK.sub(fill, text), changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 on a difference")
    args = ap.parse_args(argv)
    text, changed = render(README.read_text())
    if args.check:
        for name in changed:
            print(f"README block '{name}' differs from its evidence: python benchmarks/publish.py")
        return 1 if changed else 0
    README.write_text(text)
    print(f"rewrote {len(changed)} block(s): {', '.join(changed) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
