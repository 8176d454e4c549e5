"""Published tables written from committed evidence, never typed.

    python benchmarks/scripts/publish.py            # rewrite every block in README.md and docs/*.md
    python benchmarks/scripts/publish.py --check    # exit 1 naming each block that differs

A block is the text of a document between ``<!-- publish:NAME -->`` and
``<!-- /publish:NAME -->``; ``BLOCKS[NAME]`` writes it from the committed folders under
``benchmarks/`` (a study's ``eval/`` files as ``python -m jaxlc.evaluate`` wrote them, a
benchmark session's CSVs). Each block appears once, in one of ``DOCS``.
``tests/test_publish.py`` runs the check, so a table that no longer matches its evidence fails
the suite.
"""

from __future__ import annotations

import argparse
import csv
import dataclasses
import functools
import importlib.util
import json
import re
import sys
import tomllib
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.evaluation import stats
from jaxlc.evaluation.report import EVERY_STEP
from jaxlc.paper import claims
from jaxlc.paper.grid import is_best
from jaxlc.study.rundir import RunDir

ROOT = Path(__file__).resolve().parents[2]
README = ROOT / "README.md"
DOCS = (README, ROOT / "docs" / "results.md", ROOT / "docs" / "benchmarks.md")

# The studies the verdict rests on (configs/paper.toml's, configs/default.toml's).
PAPER_STUDY = ROOT / "benchmarks" / "study_paper_cpu_s1"
DEFAULT_STUDY = ROOT / "benchmarks" / "study_symmetric_cpu_s3"  # three seeds per cell
VERDICT_STUDY = ROOT / "benchmarks" / "study_default_cpu_s10"  # the verdict's default column
# configs/roads.toml's study, with both probes of env.curvature (roads- and straight-trained).
ROADS_STUDY = ROOT / "benchmarks" / "study_roads_cpu_s3"
# configs/joint.toml's study (lateral and longitudinal control), with today's default on the
# same seeds evaluated under the same rules (default_s3/), and its weight study (weights/).
JOINT_STUDY = ROOT / "benchmarks" / "study_joint_cpu_s3"
JOINT_GPU = ROOT / "benchmarks" / "study_joint_gpu_s8"  # eight seeds per cell on one GPU
# The benchmark session every speed figure of docs/benchmarks.md comes from.
BENCH = ROOT / "benchmarks" / "bench_cpu_2026-11-24"

# What the paper shows for each claim (its text, section IV), keyed by the claim's tag.
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


def _unlike_default(study: Path) -> str:
    """Where the study's run config differs from today's default in its method (the env,
    ddpg and grid tables), as ``; ddpg.key = value``: a default study trained before a
    default changed says so in the heading that names it."""
    ran, today = RunDir(study).load_config(), config.Config()
    return "".join(
        f"; {table}.{f.name} = {json.dumps(getattr(getattr(ran, table), f.name))}"
        for table in ("env", "ddpg", "grid")
        for f in dataclasses.fields(getattr(today, table))
        if getattr(getattr(ran, table), f.name) != getattr(getattr(today, table), f.name)
    )


def _comparisons(study: Path, claim: dict[str, str]) -> str:
    """A claim's comparisons in a study on the measures it is decided by: each side's mean over
    seeds and, from 2 seeds on, the paper-side difference with its interval and the margin
    (``jaxlc.evaluation.convergence``)."""
    parts = []
    measures = claim["measures"].split(", ")
    for c in _load(study, "convergence.json")["comparisons"]:
        if c["claim"] != claim["claim"] or c["measure"] not in measures:
            continue
        episodes = c["measure"] in _EPISODES
        fmt = "{:.0f}" if episodes else "{:.3g}"
        x, y = (("never" if v is None else fmt.format(v)) for v in (c["x_mean"], c["y_mean"]))
        text = f"{c['measure']}: {c['x']} {x} vs {c['y']} {y}{' ep' if episodes else ''}"
        if c["seeds"] > 1 and "diff" in c:
            d, lo, hi, m = (fmt.format(c[k]) for k in ("diff", "diff_lo", "diff_hi", "margin"))
            text += f", {c['x']} ahead by {d} [{lo}, {hi}] (margin ±{m})"
        elif c["seeds"] > 1:  # a study evaluated before the margins: P only
            text += f", P = {c['p']:.2f} [{c['p_lo']:.2f}, {c['p_hi']:.2f}]"
        parts.append(text)
    return "; ".join(parts)


def _claim_d(study: Path) -> tuple[str, str]:
    doc = _load(study, "heldout.json")
    cell = next(c for c in doc["cells"] if is_best(c))
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
        f"`default.toml` here ({_seeds(VERDICT_STUDY)}{_unlike_default(VERDICT_STUDY)}) | "
        "verdict (paper.toml; default.toml) |",
        "|---|---|---|---|---|",
    ]
    paper_claims = {c["claim"]: c for c in _load(PAPER_STUDY, "convergence.json")["claims"]}
    for claim in _load(VERDICT_STUDY, "convergence.json")["claims"]:
        text = claim["claim"]
        lines.append(
            f"| {text} | {claims.SHOWS[_tag(text)]} | {_comparisons(PAPER_STUDY, claim)} | "
            f"{_comparisons(VERDICT_STUDY, claim)} | {paper_claims[text]['verdict']}; "
            f"{claim['verdict']} |"
        )
    (p_text, p_verdict), (d_text, d_verdict) = _claim_d(PAPER_STUDY), _claim_d(VERDICT_STUDY)
    claim_d = _load(VERDICT_STUDY, "heldout.json")["claim_d"]["claim"]
    lines.append(
        f"| {claim_d} | {claims.SHOWS['(d)']} | {p_text} | {d_text} | {p_verdict}; {d_verdict} |"
    )
    return "\n".join(lines)


def heldout_cells(study: Path = DEFAULT_STUDY) -> str:
    """Per cell of a study (the default's unless given): held-out success (the seeds' range
    of Clopper-Pearson intervals under 5 seeds), failures and collisions with their one-sided
    95% bounds, share inside every norm."""
    lines = [
        "| cell | seeds | lane changes | success | 95% interval | failures (bound) | collisions "
        "(bound) | inside every norm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    doc = _load(study, "heldout.json")
    for c in doc["cells"]:
        lines.append(
            f"| {c['label']} | {c['seeds']} | {c['lane_changes']:,} | "
            f"{100 * c['success_mean']:.2f}% | [{100 * c['success_lo']:.2f}, "
            f"{100 * c['success_hi']:.2f}]% | {c['failures']} "
            f"(< {100 * c['failure_bound']:.2f}%) | {c['collisions']} "
            f"(< {100 * c['collision_bound']:.2f}%) | {100 * c['norm_all']:.1f}% |"
        )
    counted = doc.get("conflicts_counted", EVERY_STEP)
    return "\n".join(
        [*lines, "", f"Headway and time-to-collision counted {counted}. {_duration_rule(doc)}"]
    )


def _duration_rule(doc: dict[str, Any]) -> str:
    """Which time the evaluation held to 5 s, read off the norms ``heldout.json`` lists."""
    if any(n["measure"] == "lcm_s" for n in doc["norms"]):
        return (
            "The 5 s norm times UN R79's manoeuvre, the body from first over the line to "
            "wholly across it."
        )
    return "The 5 s norm times the whole RL phase (the rule before 2026-11-26)."


@functools.cache
def _csv(path: Path) -> tuple[dict[str, str], ...]:
    """A committed CSV's rows, read once however many blocks use it."""
    with path.open() as f:
        return tuple(csv.DictReader(f))


def _per_seed(rows: tuple[dict[str, str], ...], column: str) -> dict[str, np.ndarray]:
    """A heldout.csv column's values over each cell's seeds, by the cell's label."""
    cells: dict[str, list[float]] = {}
    for r in rows:
        if r["cell"] != "":
            cells.setdefault(r["label"], []).append(float(r[column]))
    return {label: np.asarray(v) for label, v in cells.items()}


def _per_cell(rows: tuple[dict[str, str], ...], column: str) -> dict[str, float]:
    """A heldout.csv column's mean over each cell's seeds, by the cell's label."""
    return {label: float(np.mean(v)) for label, v in _per_seed(rows, column).items()}


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
    drawn = {policy: _load(study, "heldout.json") for policy, study in studies}
    docs = {policy: {c["label"]: c for c in d["cells"]} for policy, d in drawn.items()}
    norms = ("norm_min_thw_s", "norm_lcm_s", "norm_peak_lat_acc", "norm_peak_lat_jerk")
    means = {
        policy: [_per_cell(_csv(study / "eval" / "heldout.csv"), n) for n in norms]
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
    rule = _duration_rule(drawn[name])
    return "\n".join(
        [*lines, "", f"Headway and time-to-collision counted {counted}. {rule} Gaps found: {gaps}."]
    )


PAIRS_STUDY = ROOT / "benchmarks" / "study_pairs_gpu_s10"
PAIRS_STUDY_S20 = ROOT / "benchmarks" / "study_pairs_gpu_s20"


def pairs_table(
    study: Path = PAIRS_STUDY,
    rows: str = "rows10",
    pairs: str = "pairs10",
    margin: float | None = None,
    spread: str | None = None,
) -> str:
    """``ddpg.mirror_pairs`` against mirrored batches of rows reflected at random, on one GPU
    (``study``, its runs ``rows`` and ``pairs``): per cell, held-out success and failures, and
    the convergence measures the verdict uses; then the pooled held-out difference with a 95%
    bootstrap interval (seeds resampled within cells, 10,000 resamples, generator seed 0) and
    the answer of the study's ``rule.md``, stated before its run. ``margin`` None: the first
    study's rule (an interval reaching 0, no cell 0.5 points lower); a margin (a share): the
    second's (the interval's lower end at or above -margin, no cell 0.5 points lower, no cell's
    ``auc`` 0.02 lower or ``converged`` 100 episodes later). ``spread``: a run of the rows on
    other seeds, whose difference from ``rows`` is given beside, outside the rule."""
    names = (rows, pairs) + ((spread,) if spread else ())
    held = {r: _csv(study / r / "eval" / "heldout.csv") for r in names}
    conv = {r: _csv(study / r / "eval" / "convergence.csv") for r in names}
    lines = [
        "| cell | held-out success (rows; pairs) | failures (rows; pairs) "
        "| auc (rows; pairs) | converged, episode (rows; pairs) |",
        "|---|---|---|---|---|",
    ]
    per_seed = {r: _per_seed(held[r], "success_rate") for r in names}
    success = {r: _per_cell(held[r], "success_rate") for r in names}
    auc = {r: _per_cell(conv[r], "auc") for r in names}
    converged = {r: _per_cell(conv[r], "converged") for r in names}

    def failures(r: str, label: str | None = None) -> int:
        rows_ = [x for x in held[r] if x["cell"] and label in (None, x["label"])]
        return sum(int(x["lane_changes"]) - int(x["success"]) for x in rows_)

    for label in success[rows]:
        lines.append(
            f"| {label} | {100 * success[rows][label]:.2f}%; {100 * success[pairs][label]:.2f}% "
            f"| {failures(rows, label)}; {failures(pairs, label)} | "
            f"{auc[rows][label]:.3f}; {auc[pairs][label]:.3f} | "
            f"{converged[rows][label]:.0f}; {converged[pairs][label]:.0f} |"
        )
    rng = np.random.default_rng(0)

    def pooled(cells: dict[str, np.ndarray], resample: bool) -> float:
        pick = (lambda v: rng.choice(v, v.size)) if resample else (lambda v: v)
        return float(np.mean([pick(v).mean() for v in cells.values()]))

    def difference(a: str, b: str) -> tuple[float, float, float]:
        point = pooled(per_seed[b], False) - pooled(per_seed[a], False)
        boot = [pooled(per_seed[b], True) - pooled(per_seed[a], True) for _ in range(10_000)]
        lo, hi = np.percentile(boot, [2.5, 97.5])
        return point, float(lo), float(hi)

    point, lo, hi = difference(rows, pairs)
    worst = min(success[pairs][c] - success[rows][c] for c in success[rows])
    models = sum(1 for x in held[rows] if x["cell"])
    said = (
        f"Held-out success pooled over the {models} models, pairs − rows: {100 * point:+.3f} "
        f"points, 95% interval [{100 * lo:+.3f}, {100 * hi:+.3f}]; the largest drop in a cell "
        f"{100 * -worst:.2f} points."
    )
    if margin is None:
        adopted = hi >= 0 and worst >= -0.005
        asks = "an interval reaching 0 and no cell lower by more than 0.5 points"
    else:
        auc_drop = max(auc[rows][c] - auc[pairs][c] for c in auc[rows])
        later = max(converged[pairs][c] - converged[rows][c] for c in converged[rows])
        adopted = lo >= -margin and worst >= -0.005 and auc_drop <= 0.02 and later <= 100
        said += (
            f" Per cell, `auc` at most {auc_drop:.4f} lower and `converged` at most "
            f"{later:.0f} episodes later."
        )
        asks = (
            f"the interval's lower end at or above {-100 * margin:+.2f} points, no cell lower "
            "by more than 0.5 points, `auc` at most 0.02 lower and `converged` at most 100 "
            "episodes later per cell"
        )
    lines += [
        "",
        f"{said} The rule (`rule.md`) asks for {asks}: "
        f"**{'adopted' if adopted else 'not adopted'}**.",
    ]
    if spread:
        point, lo, hi = difference(rows, spread)
        lines += [
            "",
            f"Outside the rule, the rows on other seeds (`{spread}`), {spread} − {rows}: "
            f"{100 * point:+.3f} points, 95% interval [{100 * lo:+.3f}, {100 * hi:+.3f}]; "
            f"failures {failures(rows)} ({rows}), {failures(pairs)} ({pairs}), "
            f"{failures(spread)} ({spread}) of {1000 * models:,} held-out lane changes each.",
        ]
    return "\n".join(lines)


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
        models = [r for r in _csv(path) if r["cell"] != "" and r["seed"] == "0"]
        ok = [float(r["success_rate"]) for r in models]
        low = [float(r["norm_all"]) for r in models if int(r["k"]) <= 2]
        k4 = [float(r["norm_all"]) for r in models if int(r["k"]) == 4]
        lead = [float(r["thw_crit_lead"]) for r in models]
        spans = " | ".join(f"{100 * min(x):.1f}–{100 * max(x):.1f}%" for x in (ok, low, k4, lead))
        lines.append(f"{head} | {spans} |")
    return "\n".join(lines)


GAP_FITTING = ROOT / "benchmarks" / "gap_fitting_probe"


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
    for r in _csv(GAP_FITTING / "results.csv"):
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


def roads_table() -> str:
    """The roads study's policies (``configs/roads.toml``) and the straight-trained default's
    on the same held-out lane changes of straight and curved roads (``benchmarks/scripts/probe.py
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
    rows = {name: _csv(ROADS_STUDY / name / "probe.csv") for _, name in probes}
    for kappa in dict.fromkeys(r["curvature"] for r in rows["probe_roads"]):
        for who, name in probes:
            road = "0" if float(kappa) == 0 else f"{float(kappa):+g}".replace("-", "−")
            lines.append(row(road, who, [r for r in rows[name] if r["curvature"] == kappa]))
    return "\n".join(lines)


def _bench(name: str) -> tuple[dict[str, str], ...]:
    return _csv(BENCH / name)


@functools.cache
def _timing() -> dict[str, dict[str, str]]:
    """``timing.txt`` of the benchmark session: per step, its start and end lines' fields."""
    steps: dict[str, dict[str, str]] = {}
    for line in (BENCH / "timing.txt").read_text().splitlines():
        name, what, when, *rest = line.split()
        if what in ("start", "end"):
            fields = dict(zip(rest[::2], rest[1::2], strict=False))
            steps.setdefault(name, {}).update({what: when, **fields})
    return steps


def _peaks(*names: str) -> str:
    """The matmul peaks measured around benchmark steps, as a range in GFLOP/s."""
    t = _timing()
    values = [float(t[n][k]) for n in names for k in ("peak_before_gflops", "peak_after_gflops")]
    return f"{min(values):.0f}–{max(values):.0f} GFLOP/s"


def sim_table() -> str:
    """``benchmarks/scripts/sim_throughput.py``: env-steps/s by batch size."""
    rows = _bench("sim_throughput.csv")
    best = max(rows, key=lambda r: float(r["env_steps_per_s"]))
    return "\n".join(
        [
            "| envs | " + " | ".join(f"{int(r['envs']):,}" for r in rows) + " |",
            "|---|" + "---|" * len(rows),
            "| env-steps/s | "
            + " | ".join(
                (
                    f"**{float(r['env_steps_per_s']):,.0f}**"
                    if r is best
                    else f"{float(r['env_steps_per_s']):,.0f}"
                )
                for r in rows
            )
            + " |",
            "| RL share of env-steps | "
            + " | ".join(f"{float(r['rl_share']):.1%}" for r in rows)
            + " |",
            "",
            f"Matmul peak around the run: {_peaks('sim_throughput')}.",
        ]
    )


def highway_table() -> str:
    """``benchmarks/scripts/vs_highway_env.py``: both simulators in one run, and the ratios."""
    rows = _bench("vs_highway_env.csv")
    names = {
        "single": "one env",
        "sync:2": "`SyncVectorEnv` × 2",
        "async:2": "`AsyncVectorEnv` × 2",
        "async:4": "`AsyncVectorEnv` × 4",
        "gym wrapper": "gym wrapper, one env",
        "scan": "`lax.scan`, one env",
        "scan+vmap": "`lax.scan` + `vmap`",
    }
    lines = [
        "| simulator | setting | envs | env-steps/s | RL decisions/s |",
        "|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['simulator']} | {names.get(r['setting'], r['setting'])} | {int(r['envs']):,} | "
            f"{float(r['env_steps_per_s']):,.0f} | {float(r['decisions_per_s']):,.0f} |"
        )
    rate = {(r["simulator"], r["setting"], r["envs"]): float(r["env_steps_per_s"]) for r in rows}
    hw = {k: v for k, v in rate.items() if k[0] == "highway-env"}
    jx = {k: v for k, v in rate.items() if k[0] == "jaxlc"}
    hw_best, jx_best = max(hw, key=hw.get), max(jx, key=jx.get)
    single = rate[("highway-env", "single", "1")]
    one = rate[("jaxlc", "scan", "1")] / single
    lines += [
        "",
        f"One jaxlc env (`lax.scan`) runs {one:,.0f}× one highway-env env; jaxlc's best batch "
        f"({int(jx_best[2]):,} envs) runs {jx[jx_best] / hw[hw_best]:,.0f}× highway-env's best "
        f"setting ({names[hw_best[1]]}) and {jx[jx_best] / single:,.0f}× "
        f"its single env. Matmul peak around the run: {_peaks('vs_highway_env')}.",
    ]
    return "\n".join(lines)


def update_table() -> str:
    """``benchmarks/scripts/update_throughput.py`` on 1 and on 3 host devices, and one
    update's parts."""
    lines = [
        "| models laid over | grid-updates/s | MFLOP per model update | achieved GFLOP/s | "
        "matmul peak, same process | share of peak |",
        "|---|---|---|---|---|---|",
    ]
    runs = {n: _bench(f"update_throughput_{n}dev.csv")[0] for n in (1, 3)}
    for n, r in runs.items():
        lines.append(
            f"| {n} device{'s' if n > 1 else ''} | {float(r['grid_updates_per_s']):.1f} | "
            f"{float(r['mflop_per_model_update']):.0f} | {float(r['achieved_gflops']):.1f} | "
            f"{float(r['peak_gflops']):.1f} | **{float(r['share_of_peak']):.0%}** |"
        )
    one = runs[1]
    lines += [
        "",
        "| part of one grid update (9 models, 1 device) | time | what it reaches |",
        "|---|---|---|",
        f"| the whole update | {float(one['update_ms']):.2f} ms | "
        f"{float(one['share_of_peak']):.1%} of the peak |",
        f"| its matrix products alone, at their shapes | {float(one['products_alone_ms']):.2f} ms "
        f"| {float(one['products_alone_share_of_peak']):.1%} of the peak |",
        f"| its Adam + soft-target pass alone | {float(one['optimizer_alone_ms']):.2f} ms | "
        f"{float(one['optimizer_alone_gbps']):.1f} GB/s at the minimum 36 bytes per parameter |",
        f"| a plain streamed `a + 1e-3 b` over the same footprint | – | "
        f"{float(one['stream_gbps']):.1f} GB/s |",
        f"| an update of nothing but the products and a streamed Adam pass (`share_ceiling`) | – "
        f"| {float(one['share_ceiling']):.1%} of the peak |",
        "",
        f"Matmul peak around the runs: {_peaks('update_throughput_1dev', 'update_throughput_3dev')}"
        " (the table's own column is the one measured inside each run).",
    ]
    return "\n".join(lines)


ACTORS = ROOT / "benchmarks" / "bench_actors_cpu_2026-11-26"


def actors_table() -> str:
    """``benchmarks/scripts/update_throughput.py actors``: the plain actor, the
    reflection-odd one and the odd one on paired batches side by side, each run beside the
    matmul peaks measured around it."""
    rows = _csv(ACTORS / "actors.csv")
    lines = [
        "| round | actor | MFLOP per model update | grid-updates/s | peak around the update "
        "(GFLOP/s) | default sweep env-steps/s | its wall s | peak at its end (GFLOP/s) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['round']} | {r['actor']} | {float(r['mflop_per_model_update']):.0f} | "
            f"{float(r['grid_updates_per_s']):.1f} | {float(r['peak_gflops_before_update']):.0f}"
            f"–{float(r['peak_gflops_after_update']):.0f} | "
            f"{float(r['sweep_env_steps_per_s']):,.0f} | {float(r['sweep_wall_s']):.1f} | "
            f"{float(r['sweep_peak_gflops']):.0f} |"
        )

    def mean(actor: str, key: str) -> float:
        return float(np.mean([float(r[key]) for r in rows if r["actor"] == actor]))

    def against_plain(actor: str, name: str) -> str:
        sweep = mean(actor, "sweep_env_steps_per_s") / mean("plain", "sweep_env_steps_per_s")
        update = mean(actor, "grid_updates_per_s") / mean("plain", "grid_updates_per_s")
        flops = mean(actor, "mflop_per_model_update") / mean("plain", "mflop_per_model_update")
        return (
            f"{name} **{sweep:.1%}** of the plain actor's env-steps/s in the default sweep and "
            f"{update:.1%} of its grid-updates/s, at {flops:.2f}× its matrix-product FLOPs per "
            "update"
        )

    rows_ = against_plain("odd", "the odd actor on rows (`odd`, the default until 2026-11-26)")
    pairs = against_plain("paired", "on reflection pairs (`paired`, today's default)")
    lines += ["", f"Over the rounds: {rows_}; {pairs}."]
    return "\n".join(lines)


def devices_table() -> str:
    """``benchmarks/scripts/devices_throughput.py``, one process per device count, both grids."""
    counts = (1, 2, 3)
    lines = [
        "| grid | " + " | ".join(f"N = {n}" for n in counts) + " |",
        "|---|" + "---|" * len(counts),
    ]
    steps = []
    for grid, what in (
        ("paper", "paper (9 models, 300/600, batch 64)"),
        ("smoke", "smoke (4 models, 32/32, batch 16)"),
    ):
        rows = {n: _bench(f"devices_{grid}_n{n}.csv")[0] for n in counts}
        best = max(counts, key=lambda n: float(rows[n]["grid_updates_per_s"]))
        for key, unit in (
            ("grid_updates_per_s", "grid-updates/s"),
            ("env_steps_per_s", "env-steps/s"),
        ):
            cells = []
            for n in counts:
                text = (
                    f"{float(rows[n][key]):,.1f}"
                    if key == "grid_updates_per_s"
                    else f"{float(rows[n][key]):,.0f}"
                )
                cells.append(f"**{text}**" if n == best else text)
            lines.append(f"| {what}: {unit} | " + " | ".join(cells) + " |")
        steps += [f"devices_{grid}_n{n}" for n in counts]
        one = float(rows[1]["grid_updates_per_s"])
        lines.append(
            f"| {what}: against one device | "
            + " | ".join(f"{float(rows[n]['grid_updates_per_s']) / one:.2f}×" for n in counts)
            + " |"
        )
    lines += ["", f"Matmul peak around the runs: {_peaks(*steps)}."]
    return "\n".join(lines)


def rejax_table() -> str:
    """``benchmarks/scripts/vs_rejax.py``'s rows beside jaxlc's DDPG ④ over 3 seeds: success on the
    100 fixed cases at the end, return, wall time, decisions per second, the machine's peak."""
    folder = ROOT / "benchmarks" / "vs_rejax_cpu"
    lines = [
        "| learner | decisions per seed | success, mean [seeds' range] (per seed) | return | "
        "wall, 3 seeds in one program | decisions/s | matmul peak |",
        "|---|---|---|---|---|---|---|",
    ]
    ddpg = [r for r in _csv(folder / "ddpg_d4_s3_eval.csv") if r["episode"] == "5000"]
    success = [int(r["success"]) / int(r["performed"]) for r in ddpg]
    summary = (folder / "ddpg_d4_s3_summary.md").read_text()
    wall, steps, peak = (
        float(x.replace(",", ""))
        for x in re.search(r"Wall time (\d+) s, ([\d,]+) env-steps.* (\d+) GFLOP", summary).groups()
    )
    lines.append(
        f"| **jaxlc DDPG ④** (k = 1, D = 4000, the defaults of then) | not recorded: 5000 "
        f"episodes, {steps / 3 / 1e6:.2f} M env-steps (traffic included) | "
        f"**{100 * np.mean(success):.1f}%** "
        f"[{100 * min(success):.1f}, {100 * max(success):.1f}] "
        f"({', '.join(f'{x:.2f}' for x in success)}) | "
        f"{np.mean([float(r['avg_return']) for r in ddpg]):.1f} | {wall:.0f} s (compile "
        f"included) | – | {peak:.0f} GFLOP/s |"
    )
    names = {
        "rejax ppo": "Rejax PPO (`normalize_rewards`)",
        "rejax td3": "Rejax TD3",
        "rejax sac": "Rejax SAC",
    }
    rows = _csv(folder / "vs_rejax_ppo.csv") + _csv(folder / "vs_rejax_offpolicy.csv")
    for r in rows:
        per = ", ".join(r["success_per_seed"].split())
        lines.append(
            f"| {names[r['learner']]} | {int(r['decisions_per_seed']) // 1000} k | "
            f"{100 * float(r['success_mean']):.1f}% [{100 * float(r['success_lo']):.1f}, "
            f"{100 * float(r['success_hi']):.1f}] ({per}) | {float(r['return_mean']):.1f} | "
            f"{float(r['train_s']):.0f} s (+ {float(r['compile_s']):.1f} s compile) | "
            f"{int(r['decisions_per_s']):,} | {r['matmul_peak_gflops']} GFLOP/s |"
        )
    return "\n".join(lines).replace("| -", "| −")


def scripted_noise_table() -> str:
    """``benchmarks/scripts/scripted_under_noise.py``: the scripted controller's success under the
    training noise, by k and σ, with the lane changes behind each figure."""
    rows = _bench("scripted_under_noise.csv")
    ks = list(dict.fromkeys(r["k"] for r in rows))
    sigmas = list(dict.fromkeys(r["sigma"] for r in rows))
    at = {(r["k"], r["sigma"]): r for r in rows}
    lines = [
        "| k | " + " | ".join(f"σ = {float(x):g}" for x in sigmas) + " |",
        "|---|" + "---|" * len(sigmas),
    ]
    for k in ks:
        cells = [at[k, x] for x in sigmas]
        lines.append(
            f"| {k} | "
            + " | ".join(
                f"{100 * float(c['success_rate']):.2f}% (of {int(c['lane_changes']):,})"
                for c in cells
            )
            + " |"
        )
    ends = [sum(int(r[e]) for r in rows) for e in ("timeout", "out_of_bounds", "collision")]
    failed = sum(int(r["lane_changes"]) - int(r["success"]) for r in rows)
    lines += [
        "",
        f"Of the {failed:,} lane changes that failed, {ends[0]:,} timed out, {ends[1]:,} went out "
        f"of bounds and {ends[2]:,} collided.",
    ]
    return "\n".join(lines)


def time_to_solution() -> str:
    """``benchmarks/scripts/time_to_solution.py`` on the default study: one sentence from its
    CSV."""
    (r,) = _bench("time_to_solution.csv")
    t = _timing()["time_to_solution"]
    if r["reached"] != "True":
        return f"Not reached within {float(r['wall_s']):.0f} s on {r['devices']} host devices."
    return (
        f"**{float(r['wall_s']):.1f} s** on {r['devices']} host devices ({r['date']}); the "
        f"machine's float32 matmul peak measured {r['matmul_peak_gflops']} GFLOP/s inside the "
        f"run and {float(t['peak_before_gflops']):.0f}–{float(t['peak_after_gflops']):.0f} "
        f"GFLOP/s right before and after it. {r['model']} seed {r['seed']} reached "
        f"{float(r['success_last']):.0%} at episode {int(r['episode']):,}, after "
        f"{int(r['env_steps']) / 1e6:.2f} M env-steps of the {r['models']} models."
    )


def sb3_table() -> str:
    """``benchmarks/scripts/vs_sb3.py``: one model of each learner to the target, then nine
    models to the episode SB3 reached (jaxlc's grid measured, SB3's nine runs extrapolated from
    one)."""
    sb3, jx, grid, sb3_nine = _bench("vs_sb3.csv")

    def target(r: dict[str, str]) -> str:
        if r["time_to_target_s"] in ("", "nan"):
            return f"not reached in {float(r['wall_s']):.0f} s ({int(r['episodes']):,} episodes)"
        return (
            f"{float(r['time_to_target_s']):.0f} s (episode {int(float(r['episode_of_target'])):,})"
        )

    lines = [
        "| one model | updates/s | RL transitions/s | transitions per update | compile s | "
        "time to the target |",
        "|---|---|---|---|---|---|",
    ]
    for who, r in (("SB3 DDPG, one env", sb3), ("jaxlc, 32 envs", jx)):
        lines.append(
            f"| {who} | {float(r['updates_per_s']):,.0f} | {float(r['transitions_per_s']):,.0f} | "
            f"{int(r['transitions']) / max(int(r['updates']), 1):.1f} | "
            f"{float(r['compile_s']):.1f} | {target(r)} |"
        )
    ratio = float(sb3_nine["wall_s"]) / float(grid["wall_s"])
    faster = float(sb3["time_to_target_s"]) / float(jx["time_to_target_s"])
    lines += [
        "",
        f"To the target, one jaxlc model was {faster:.1f}× faster than one SB3 model (in more "
        "episodes: it makes fewer updates per transition).",
        "",
        f"Nine models to episode {int(sb3_nine['episodes']):,} each: the jaxlc grid took "
        f"{float(grid['wall_s']):.0f} s (measured); nine SB3 runs one after another would take "
        f"{float(sb3_nine['wall_s']):.0f} s (extrapolated: 9 × the measured run's time to that "
        f"episode): {ratio:.1f}×, at equal episodes, not at equal success. Matmul peak around "
        f"the run: {_peaks('vs_sb3')}.",
    ]
    return "\n".join(lines)


def _script(name: str) -> Any:
    """A sibling script of this folder as a module (this file also runs from the tests)."""
    spec = importlib.util.spec_from_file_location(name, Path(__file__).parent / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def study_cells(eval_csv: Path) -> str:
    """``benchmarks/scripts/study_summary.py`` on a study's committed ``eval.csv``: per cell the
    success at the last checkpoint over seeds, the best checkpoint and the drop to the last,
    the lane changes' duration, peak lateral acceleration and overshoot."""
    summary = _script("study_summary")
    return summary.summary(summary.load(eval_csv)).rstrip("\n")


# The GPU study's settings (its folders under study_gpu_8seeds/), against its first row.
GPU_STUDY = ROOT / "benchmarks" / "study_gpu_8seeds"
GPU_SETTINGS = (
    ("default", "`ddpg.huber_delta=0 ddpg.mirror=false` (the morning's default)"),
    ("tterm", "… `env.terminal_timeout=true`"),
    ("rs01", "… `env.reward_scale=0.1`"),
    ("ups2", "… `ddpg.updates_per_step=2`"),
    ("mirror", "… `ddpg.mirror=true`"),
    ("mirror_ups2", "… `ddpg.mirror=true ddpg.updates_per_step=2`"),
    ("huber10", "… `ddpg.huber_delta=10`"),
    (
        "mirror_huber",
        "… `ddpg.huber_delta=10 ddpg.mirror=true` (the default before the odd "
        "actor and the gap test)",
    ),
)


def _final_success(folder: Path) -> tuple[np.ndarray, np.ndarray]:
    """``(success, seed)`` of every model at its last evaluated checkpoint, ``(models,)``."""
    rows = [r for r in _csv(folder / "eval.csv") if r["model"] != ""]
    last = max(int(r["episode"]) for r in rows)
    final = [r for r in rows if int(r["episode"]) == last]
    return np.array([float(r["success_rate"]) for r in final]), np.array(
        [int(r["seed"]) for r in final]
    )


def _studies_at(success: np.ndarray, seeds: np.ndarray, level: float = 0.99) -> tuple[int, int]:
    """Read as one-seed studies (the models of one seed each): ``(how many have a model at
    >= level, how many studies)``."""
    best = [success[seeds == s].max() for s in np.unique(seeds)]
    return sum(b >= level for b in best), len(best)


def moved_table() -> str:
    """What moved the learning: per GPU setting its sweep's wall time, the mean evaluated
    success of its 72 models and the difference from the first row with its 95% interval
    (``jaxlc.evaluation.stats.difference``), the cells whose own difference interval
    (``compare/``) lies above / below zero, and the models and one-seed studies at >= 99%."""

    def signed(x: float) -> str:
        return f"{100 * x:+.1f}".replace("-", "−")

    base, _ = _final_success(GPU_STUDY / "default")
    lines = [
        f"| setting | sweep wall | success at 5000, mean of {base.size} | difference [95% CI] | "
        "cells up / down | models ≥ 99% | one-seed studies with a ≥ 99% model |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, label in GPU_SETTINGS:
        folder = GPU_STUDY / name
        wall = re.search(r"Wall time (\d+) s", (folder / "sweep.log").read_text())[1]
        success, seeds = _final_success(folder)
        studies = "{} of {}".format(*_studies_at(success, seeds))
        diff = cells = "–"
        if name != "default":
            d, lo, hi = stats.difference(base, success)
            diff = f"{signed(d)} [{signed(lo)}, {signed(hi)}]"
            rows = _csv(GPU_STUDY / "compare" / f"default_vs_{name}" / "compare.csv")
            up = sum(float(r["diff_lo"]) > 0 for r in rows)
            cells = f"{up} / {sum(float(r['diff_hi']) < 0 for r in rows)}"
        lines.append(
            f"| {label} | {wall} s | {100 * success.mean():.1f}% | {diff} | {cells} | "
            f"{int(np.sum(success >= 0.99))} | {studies} |"
        )
    return "\n".join(lines)


_REPORT_ROW = re.compile(
    r"^\| (?P<label>[^|]+?) \| (?P<seed>[^|]*?) \| (?P<episode>[^|]+?) \| (?P<performed>\d+)/\d+ "
    r"\| (?P<rate>[\d.]+)% \| (?P<ret>-?[\d.]+) \| (?P<success>\d+) \|",
    re.M,
)


def one_seed_table(folder: Path) -> str:
    """A one-seed study of 2026-11-22 from what it committed (``report.md``'s checkpoint rows,
    ``summary.md``'s last-100 training success): per model its training success, its
    evaluation at the last checkpoint, and its best checkpoint."""
    rows = [m.groupdict() for m in _REPORT_ROW.finditer((folder / "report.md").read_text())]
    training = dict(
        re.findall(
            r"^\| ([^|]+?) \| 0 \| \d+ \| ([\d.]+)% \|", (folder / "summary.md").read_text(), re.M
        )
    )
    lines = [
        "| model | training: success, last 100 episodes | evaluation at episode 5000: success "
        "(of lane changes) | average return | best checkpoint: success |",
        "|---|---|---|---|---|",
    ]
    labels = list(dict.fromkeys(r["label"] for r in rows))
    for label in labels:
        mine = [r for r in rows if r["label"] == label]
        last = max(mine, key=lambda r: int(r["episode"]) if r["episode"].isdigit() else 0)
        evaluated = f"{float(last['rate']):.1f}% ({last['success']}/{last['performed']})"
        ret = last["ret"].replace("-", "−")
        if label == "scripted controller":
            lines.append(f"| {label} | – | {evaluated} | {ret} | – |")
            continue
        best = max(mine, key=lambda r: (float(r["rate"]), -int(r["episode"])))
        lines.append(
            f"| {label} | {float(training[label]):.0f}% | {evaluated} | {ret} | "
            f"{float(best['rate']):.1f}% at {best['episode']} |"
        )
    return "\n".join(lines)


def _largest_drop(eval_csv: Path) -> tuple[int, float]:
    """``(last episode, largest drop)``: how far a cell's mean success over seeds at the last
    checkpoint lies below its best checkpoint's, the most of any cell."""
    by_cell: dict[str, dict[int, list[float]]] = {}
    for r in _csv(eval_csv):
        if r["model"] != "":
            cell = by_cell.setdefault(r["label"], {})
            cell.setdefault(int(r["episode"]), []).append(float(r["success_rate"]))
    last = max(max(eps) for eps in by_cell.values())
    drop = max(
        max(np.mean(v) for v in eps.values()) - np.mean(eps[last]) for eps in by_cell.values()
    )
    return last, float(drop)


def targets_table() -> str:
    """The "every seed learns" targets against the GPU study of eight seeds (its eval.csv and
    summary.json), the CPU study that evaluated every checkpoint, and both time-to-solution
    runs; each verdict follows from the figures beside it."""
    gpu = GPU_STUDY / "mirror_huber"
    rows = [r for r in _csv(gpu / "eval.csv") if r["model"] != "" and r["episode"] == "5000"]
    cells: dict[str, list[dict[str, str]]] = {}
    for r in rows:
        cells.setdefault(r["label"], []).append(r)
    mean = {c: np.mean([float(r["success_rate"]) for r in rs]) for c, rs in cells.items()}
    k = {c: int(rs[0]["k"]) for c, rs in cells.items()}
    four = next(
        c for c, rs in cells.items() if is_best({"k": k[c], "memory": int(rs[0]["memory"])})
    )
    d = stats.describe(np.array([float(r["success_rate"]) for r in cells[four]]))
    small = [mean[c] for c in cells if k[c] != 4]
    big = [mean[c] for c in cells if k[c] == 4]
    cases = sum(int(r["performed"]) for r in rows)
    collided = sum(int(r["collision"]) for r in rows)
    ends = [
        m["ends_last"]["collision"]
        for m in json.loads((gpu / "summary.json").read_text())["models"]
    ]
    studies, n_studies = _studies_at(*_final_success(gpu))
    last_ep, drop = _largest_drop(
        ROOT / "benchmarks" / "study_default_cpu_s3" / "eval" / "eval.csv"
    )
    durations = [float(r["duration_s"]) for r in rows if r["duration_s"]]
    (now,) = _bench("time_to_solution.csv")
    (then,) = _csv(ROOT / "benchmarks" / "study_default_cpu_s3" / "time_to_solution.csv")
    scaled = float(now["wall_s"]) * float(now["matmul_peak_gflops"]) / 200

    def met(ok: bool) -> str:
        return "met" if ok else "not met"

    dur = [
        np.mean([float(r["duration_s"]) for r in rs if r["duration_s"]]) for rs in cells.values()
    ]
    lines = [
        '| target ("every seed learns") | measured | |',
        "|---|---|---|",
        f"| ④ mean evaluated success ≥ 95% over 8 seeds | {100 * d['mean']:.1f}% "
        f"[{100 * d['mean_lo']:.1f}, {100 * d['mean_hi']:.1f}] (GPU) | {met(d['mean'] >= 0.95)} |",
        f"| every k ≤ 2 cell ≥ 90%; every k = 4 cell ≥ 75% | k ≤ 2: {100 * min(small):.1f}–"
        f"{100 * max(small):.1f}%; k = 4: {100 * min(big):.1f}–{100 * max(big):.1f}% (GPU) | "
        f"{met(min(small) >= 0.9 and min(big) >= 0.75)} |",
        f"| no collisions | evaluation: {collided} in {cases:,} model-cases (GPU); training (noise "
        f"on): {sum(ends)} collisions in the last 100 episodes of the {len(ends)} models, "
        f"{sum(e > 0 for e in ends)} models with one or more ([`summary.json`]"
        f"(../benchmarks/study_gpu_8seeds/mirror_huber/summary.json)) | "
        f"{met(collided == 0)} in evaluation, {met(sum(ends) == 0)} in training |",
        f"| ≥ 7 of 8 one-seed studies with a model at ≥ 99% | {studies} of {n_studies} (GPU) | "
        f"{met(studies >= 7)} |",
        f"| each cell's mean at {last_ep} within 5 points of its best checkpoint | largest drop "
        f"{100 * drop:.1f} points (CPU, 3 seeds, every checkpoint evaluated: "
        f"[`study_default_cpu_s3/`](../benchmarks/study_default_cpu_s3/)) | "
        f"{met(drop <= 0.05)} (CPU) |",
        f"| lane change 3–8 s | per cell {min(dur):.1f}–{max(dur):.1f} s (GPU; per model "
        f"{min(durations):.1f}–{max(durations):.1f} s) | "
        f"{met(3 <= min(durations) and max(durations) <= 8)} |",
        f"| time to solution ≤ 4 min on a 200 GFLOP/s CPU | {float(now['wall_s']):.1f} s at "
        f"{float(now['matmul_peak_gflops']):.0f} GFLOP/s ({now['date']}), ≈ {scaled:.0f} s scaled "
        f"to 200 GFLOP/s by the peaks' ratio; {float(then['wall_s']):.1f} s at "
        f"{float(then['matmul_peak_gflops']):.0f} GFLOP/s ({then['date']}, that day's default) | "
        f"{met(scaled <= 240)} by today's run scaled; "
        f"{met(float(then['wall_s']) <= 240 and float(then['matmul_peak_gflops']) <= 200)} on the "
        "slower VM |",
        "| time to solution ≤ 10 s on a GPU | not measured | open |",
    ]
    return "\n".join(lines)


# Studies of study_joint_cpu_s3 set beside the default's seeds 0-2: block, folder, row label.
BESIDE_DEFAULT_S3 = {
    "idm-reward": ("idm_reward_s3", "idm + reward"),
    "joint-assist": ("assist_s3", "joint + assist"),
    "joint-assist-w200": ("assist_w200_s3", "assist + w200"),
    "joint-assist-a25": ("assist_a25_s3", "assist + w200, a=0.25"),
    "joint-assist-hold": ("assist_hold_s3", "joint_assist.toml"),
}

BLOCKS: dict[str, Callable[[], str]] = {
    "verdict": verdict_table,
    "heldout-cells": heldout_cells,
    "heldout-cells-s10": lambda: heldout_cells(VERDICT_STUDY),
    "roads": roads_table,
    "joint": lambda: joint_table(JOINT_STUDY / "default_s3", JOINT_STUDY),
    "joint-gpu": lambda: joint_table(JOINT_GPU / "default8", JOINT_GPU / "joint8"),
    **{
        name: functools.partial(
            joint_table, JOINT_STUDY / "default_s3", JOINT_STUDY / folder, label
        )
        for name, (folder, label) in BESIDE_DEFAULT_S3.items()
    },
    "gap-fitting": gap_fitting_table,
    "pairs": pairs_table,
    "pairs-s20": functools.partial(
        pairs_table, PAIRS_STUDY_S20, "rows20", "pairs20", 0.0005, "rows20b"
    ),
    "joint-weights": joint_weights_table,
    "sim": sim_table,
    "highway": highway_table,
    "update": update_table,
    "actors": actors_table,
    "devices": devices_table,
    "rejax": rejax_table,
    "sb3": sb3_table,
    "scripted-noise": scripted_noise_table,
    "time-to-solution": time_to_solution,
    "plain-actor-cells": lambda: heldout_cells(ROOT / "benchmarks" / "study_heldout_cpu_s3"),
    "gpu8-cells": lambda: study_cells(GPU_STUDY / "mirror_huber" / "eval.csv"),
    "squared-s3-cells": lambda: study_cells(
        ROOT / "benchmarks" / "study_default_s3" / "eval" / "eval.csv"
    ),
    "moved": moved_table,
    "paper-run": lambda: one_seed_table(ROOT / "benchmarks" / "paper_run"),
    "tuned-run": lambda: one_seed_table(ROOT / "benchmarks" / "tuned_run"),
    "targets": targets_table,
}
_BLOCK = re.compile(r"(<!-- publish:([\w-]+) -->\n)(.*?)(<!-- /publish:\2 -->)", re.S)


def render(text: str) -> tuple[str, list[str]]:
    """``(new text, names of the blocks that changed)``; an unknown block name is an error."""
    changed: list[str] = []

    def fill(m: re.Match[str]) -> str:
        name = m.group(2)
        if name not in BLOCKS:
            raise SystemExit(f"block '{name}': no writer in benchmarks/scripts/publish.py")
        body = BLOCKS[name]() + "\n"
        if body != m.group(3):
            changed.append(name)
        return m.group(1) + body + m.group(4)

    return _BLOCK.sub(fill, text), changed


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--check", action="store_true", help="write nothing; exit 1 on a difference")
    args = ap.parse_args(argv)
    differ = []
    for doc in DOCS:
        text, changed = render(doc.read_text())
        differ += [f"{doc.relative_to(ROOT)} block '{name}'" for name in changed]
        if not args.check:
            doc.write_text(text)
    if args.check:
        for where in differ:
            print(f"{where} differs from its evidence: python benchmarks/scripts/publish.py")
        return 1 if differ else 0
    print(f"rewrote {len(differ)} block(s): {', '.join(differ) or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
