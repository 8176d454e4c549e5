"""Away from home: the roads study's policies and the straight-trained default's on held-out
lane changes of straight and curved roads; every config's policies on the held-out suite."""

from __future__ import annotations

from benchmarks.tables.common import BENCHMARKS, csv_rows, load
from jaxlc import config
from jaxlc.evaluation.results import HeldoutRow

# configs/roads.toml's study, with both probes of env.curvature (roads- and straight-trained).
ROADS_STUDY = BENCHMARKS / "study_roads_cpu_s3"
# Every config's run on the held-out suite (configs/suite.toml), three seeds each.
SUITE_STUDY = BENCHMARKS / "study_suite_cpu_s3"
# The suite table's columns: a config of suite.csv and its header.
SUITE_CONFIGS = (
    ("any_road", "`any_road`"),
    ("any_road_chosen", "`any_road`, `--choose`"),
    ("any_road_chosen_seeds4to6", "`any_road` seeds 4–6, `--choose`"),
    ("any_road_floor_chosen_seeds7to9", "`any_road` ≥ 16.8 km/h, seeds 7–9, `--choose`"),
    (
        "any_road_held_aware_chosen_seeds13to15",
        "**`any_road` as committed**, seeds 13–15, `--choose`",
    ),
    ("default", "`default`"),
    ("roads", "`roads`"),
    ("reactive", "`reactive`"),
)


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


def suite_table() -> str:
    """Per setting and config: the cells whose seeds' pooled success is >= 99.9%, the lowest
    and highest cell, the timeouts / collisions of every model; the scripted controller's
    row of the first config's run."""
    rows = csv_rows(SUITE_STUDY / "suite.csv")
    heads = " | ".join(head for _, head in SUITE_CONFIGS)
    lines = [
        f"| setting | {heads} | scripted controller |",
        "|---" * (len(SUITE_CONFIGS) + 2) + "|",
    ]
    for setting in dict.fromkeys(r["setting"] for r in rows):
        mine = [r for r in rows if r["setting"] == setting]
        entries = []
        for name, _ in SUITE_CONFIGS:
            models = [r for r in mine if r["config"] == name and r["cell"] != ""]
            cells: dict[str, list[int]] = {}
            for r in models:
                n = cells.setdefault(r["label"], [0, 0])
                n[0] += int(r["success"])
                n[1] += int(r["lane_changes"])
            rate = {label: ok / total for label, (ok, total) in cells.items()}
            lo, hi = min(rate, key=rate.get), max(rate, key=rate.get)
            ends = [sum(int(r[k]) for r in models) for k in ("timeout", "collision")]
            entries.append(
                f"{sum(v >= 0.999 for v in rate.values())} of {len(rate)}; "
                f"{100 * rate[lo]:.2f}% ({lo.split()[0]}) – {100 * rate[hi]:.2f}%; "
                f"{ends[0]:,} / {ends[1]:,}"
            )
        (script,) = [r for r in mine if r["config"] == SUITE_CONFIGS[0][0] and r["cell"] == ""]
        done = f"{int(script['success']):,} of {int(script['lane_changes']):,}"
        name = setting.replace("curve_", "curve ")
        lines.append(f"| {name} | {' | '.join(entries)} | {done} |")
    return "\n".join(lines)


BLOCKS = {"roads": roads_table, "suite": suite_table}
