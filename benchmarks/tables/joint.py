"""Lateral and longitudinal control together: the joint policies beside today's default on
the same seeds, on the CPU (three seeds) and on a GPU (eight)."""

from __future__ import annotations

from pathlib import Path

from benchmarks.tables.common import BENCHMARKS, csv_rows, duration_rule, load, per_cell
from jaxlc.evaluation.results import HeldoutRow

# configs/joint.toml's study (lateral and longitudinal control), with today's default on the
# same seeds evaluated under the same rules (default_s3/), and configs/joint_assist.toml's.
JOINT_STUDY = BENCHMARKS / "study_joint_cpu_s3"
JOINT_GPU = BENCHMARKS / "study_joint_gpu_s8"  # eight seeds per cell on one GPU


def joint_table(default: Path, joint: Path, name: str = "joint") -> str:
    """Per cell, the joint policies (``configs/joint.toml``, evaluated in ``joint``) beside
    today's default's on the same seeds (``default``), held-out lane changes under the same
    rules: success (mean over seeds, the two-level interval), collisions with their one-sided
    95% bound, the share inside every norm, and each norm's share (headway, UN R79's
    manoeuvre time, lateral acceleration and jerk; TTC holds in every lane change). ``name``
    labels the second study's rows."""
    lines = [
        "| cell | policy | lane changes | success | 95% interval | collisions (bound) "
        "| inside every norm | headway ≥ 0.9 s | R79 manoeuvre < 5 s | lat. acc. ≤ 3 m/s² "
        "| lat. jerk ≤ 5 m/s³ |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    studies = (("default", default), (name, joint))
    drawn = {policy: load(study, "heldout.json") for policy, study in studies}
    docs = {policy: {c.label: c for c in d.cells} for policy, d in drawn.items()}
    norms = ("norm_min_thw_s", "norm_lcm_s", "norm_peak_lat_acc", "norm_peak_lat_jerk")
    means = {
        policy: [per_cell(csv_rows(study / "eval" / "heldout.csv", HeldoutRow), n) for n in norms]
        for policy, study in studies
    }
    for label in docs[name]:
        for policy, _ in studies:
            c = docs[policy][label]
            shares = " | ".join(f"{100 * m[label]:.1f}%" for m in means[policy])
            lines.append(
                f"| {label} | {policy} | {c.lane_changes:,} | {100 * c.success_mean:.2f}% | "
                f"[{100 * c.success_lo:.2f}, {100 * c.success_hi:.2f}]% | "
                f"{c.collisions} (< {100 * c.collision_bound:.2f}%) | "
                f"{100 * c.norm_all:.1f}% | {shares} |"
            )
    counted = drawn[name].conflicts_counted
    gaps = "; ".join(
        f"{policy}: {d.cases:,} cases drawn for {d.lane_changes:,} lane changes, "
        f"{100 * (1 - d.lane_changes / d.cases):.1f}% with no lane change"
        for policy, d in drawn.items()
    )
    rule = duration_rule(drawn[name])
    return "\n".join(
        [*lines, "", f"Headway and time-to-collision counted {counted}. {rule} Gaps found: {gaps}."]
    )


BLOCKS = {
    "joint": lambda: joint_table(JOINT_STUDY / "default_s3", JOINT_STUDY),
    "joint-gpu": lambda: joint_table(JOINT_GPU / "default8", JOINT_GPU / "joint8"),
    "joint-assist-hold": lambda: joint_table(
        JOINT_STUDY / "default_s3", JOINT_STUDY / "assist_hold_s3", "joint_assist.toml"
    ),
}
