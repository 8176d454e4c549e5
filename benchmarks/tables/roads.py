"""Curved roads: the roads study's policies and the straight-trained default's on held-out
lane changes of straight and curved roads."""

from __future__ import annotations

from benchmarks.tables.common import BENCHMARKS, csv_rows, load
from jaxlc import config
from jaxlc.evaluation.results import HeldoutRow

# configs/roads.toml's study, with both probes of env.curvature (roads- and straight-trained).
ROADS_STUDY = BENCHMARKS / "study_roads_cpu_s3"


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

    def row(road: str, who: str, mine: list[HeldoutRow]) -> str:
        models = [r for r in mine if r.seed is not None]
        (script,) = [r for r in mine if r.seed is None]
        n = models[0].lane_changes
        succ = [r.success / n for r in models]
        ends = [sum(r[k] for r in models) for k in ("collision", "out_of_bounds", "timeout")]
        return (
            f"| {road} | {who} | {len(models)} | {n:,} | "
            f"{100 * min(succ):.1f}% – {100 * max(succ):.1f}% | "
            f"{' / '.join(f'{e:,}' for e in ends)} | "
            f"{script.success:,} of {script.lane_changes:,} |"
        )

    drawn = config.load(ROADS_STUDY / "config.toml").env.curvature
    road = f"drawn from [{drawn[0]:g}, {drawn[1]:g}]".replace("-", "−")
    lines.append(row(road, "`roads.toml`", load(ROADS_STUDY, "heldout.json").rows))
    probes = [("`roads.toml`", "probe_roads"), ("`default.toml` (straight)", "probe_straight")]
    rows = {name: csv_rows(ROADS_STUDY / name / "probe.csv", HeldoutRow) for _, name in probes}
    for kappa in dict.fromkeys(r.get("curvature") for r in rows["probe_roads"]):
        for who, name in probes:
            road = "0" if kappa == 0 else f"{kappa:+g}".replace("-", "−")
            lines.append(row(road, who, [r for r in rows[name] if r.get("curvature") == kappa]))
    return "\n".join(lines)


BLOCKS = {"roads": roads_table}
