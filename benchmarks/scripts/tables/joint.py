"""Lateral and longitudinal control together: the joint policies beside today's default on
the same seeds, the joint reward's weight study, the gap-fitting controller."""

from __future__ import annotations

import functools
import tomllib
from pathlib import Path

from tables.common import BENCHMARKS, csv_rows, duration_rule, load, per_cell

# configs/joint.toml's study (lateral and longitudinal control), with today's default on the
# same seeds evaluated under the same rules (default_s3/), and its weight study (weights/).
JOINT_STUDY = BENCHMARKS / "study_joint_cpu_s3"
JOINT_GPU = BENCHMARKS / "study_joint_gpu_s8"  # eight seeds per cell on one GPU
GAP_FITTING = BENCHMARKS / "gap_fitting_probe"  # benchmarks/scripts/gap_fitting.py
# Studies of study_joint_cpu_s3 set beside the default's seeds 0-2: block, folder, row label.
BESIDE_DEFAULT_S3 = {
    "idm-reward": ("idm_reward_s3", "idm + reward"),
    "joint-assist": ("assist_s3", "joint + assist"),
    "joint-assist-w200": ("assist_w200_s3", "assist + w200"),
    "joint-assist-a25": ("assist_a25_s3", "assist + w200, a=0.25"),
    "joint-assist-hold": ("assist_hold_s3", "joint_assist.toml"),
}


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
    docs = {policy: {c["label"]: c for c in d["cells"]} for policy, d in drawn.items()}
    norms = ("norm_min_thw_s", "norm_lcm_s", "norm_peak_lat_acc", "norm_peak_lat_jerk")
    means = {
        policy: [per_cell(csv_rows(study / "eval" / "heldout.csv"), n) for n in norms]
        for policy, study in studies
    }
    for label in docs[name]:
        for policy, _ in studies:
            c = docs[policy][label]
            shares = " | ".join(f"{100 * m[label]:.1f}%" for m in means[policy])
            lines.append(
                f"| {label} | {policy} | {c['lane_changes']:,} | {100 * c['success_mean']:.2f}% | "
                f"[{100 * c['success_lo']:.2f}, {100 * c['success_hi']:.2f}]% | "
                f"{c['collisions']} (< {100 * c['collision_bound']:.2f}%) | "
                f"{100 * c['norm_all']:.1f}% | {shares} |"
            )
    counted = drawn[name]["conflicts_counted"]
    gaps = "; ".join(
        f"{policy}: {d['cases']:,} cases drawn for {d['lane_changes']:,} lane changes, "
        f"{100 * (1 - d['lane_changes'] / d['cases']):.1f}% with no lane change"
        for policy, d in drawn.items()
    )
    rule = duration_rule(drawn[name])
    return "\n".join(
        [*lines, "", f"Headway and time-to-collision counted {counted}. {rule} Gaps found: {gaps}."]
    )


def joint_weights_table() -> str:
    """The joint reward's weight study (seed 0 of each setting, one folder per run under
    ``weights/``, the lateral-only control among them): per setting, over its nine models,
    the range per model of held-out success, inside every norm (k <= 2 and k = 4) and lane
    changes under 0.9 s of headway to the target lane's lead."""
    lines = [
        "| `longitudinal` | `w_headway` | `w_lat_acc`, `w_lat_jerk` | success per model "
        "| inside every norm (k ≤ 2) | inside every norm (k = 4) "
        "| headway to the target lead under 0.9 s |",
        "|---|---|---|---|---|---|---|",
    ]
    settings = []
    for folder in (JOINT_STUDY / "weights").iterdir():
        env = tomllib.loads((folder / "config.toml").read_text())["env"]
        key = (env["longitudinal"] != "policy", env["w_lat_acc"], env["w_headway"])
        settings.append((key, env["longitudinal"], env["w_lat_jerk"], folder))
    rows = [
        (f"| {longitudinal} | {headway:g} | {lat_acc:g}, {lat_jerk:g}", folder / "heldout.csv")
        for (_, lat_acc, headway), longitudinal, lat_jerk, folder in sorted(settings)
    ]
    # today's default on the same seed: the paper's three terms alone, lateral control alone
    rows.append(("| idm (today's default) | – | –", JOINT_STUDY / "default_s3/eval/heldout.csv"))
    for head, path in rows:
        models = [r for r in csv_rows(path) if r["cell"] != "" and r["seed"] == "0"]
        ok = [float(r["success_rate"]) for r in models]
        low = [float(r["norm_all"]) for r in models if int(r["k"]) <= 2]
        k4 = [float(r["norm_all"]) for r in models if int(r["k"]) == 4]
        lead = [float(r["thw_crit_lead"]) for r in models]
        spans = " | ".join(f"{100 * min(x):.1f}–{100 * max(x):.1f}%" for x in (ok, low, k4, lead))
        lines.append(f"{head} | {spans} |")
    return "\n".join(lines)


def gap_fitting_table() -> str:
    """The gap-fitting controller against the scripted baseline (``gap_fitting.py``): per
    config, whether the manoeuvre time is observed, held-out seed and controller, the
    outcomes and the shares inside every norm and inside the headway norm."""
    lines = [
        "| config | time observed | held-out seed | controller | lane changes | success "
        "| collisions | timeouts | inside every norm | headway ≥ 0.9 s | lead / lag under 0.9 s "
        "| manoeuvre starts after |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in csv_rows(GAP_FITTING / "results.csv"):
        n = int(r["lane_changes"])
        lines.append(
            f"| `{Path(r['config']).name}` | {'yes' if r['time_observed'] == 'True' else 'no'} "
            f"| {r['seed']} | {r['controller']} | {n:,} | {100 * int(r['success']) / n:.1f}% "
            f"| {r['collision']} | {r['timeout']} | {100 * float(r['norm_all']):.1f}% "
            f"| {100 * float(r['norm_min_thw_s']):.1f}% "
            f"| {100 * float(r['thw_crit_lead']):.1f}% / {100 * float(r['thw_crit_lag']):.1f}% "
            f"| {float(r['lcm_start_s']):.2f} s |"
        )
    return "\n".join(lines)


BLOCKS = {
    "joint": lambda: joint_table(JOINT_STUDY / "default_s3", JOINT_STUDY),
    "joint-gpu": lambda: joint_table(JOINT_GPU / "default8", JOINT_GPU / "joint8"),
    **{
        name: functools.partial(
            joint_table, JOINT_STUDY / "default_s3", JOINT_STUDY / folder, label
        )
        for name, (folder, label) in BESIDE_DEFAULT_S3.items()
    },
    "joint-weights": joint_weights_table,
    "gap-fitting": gap_fitting_table,
}
