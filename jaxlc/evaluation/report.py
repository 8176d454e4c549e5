"""``RUN_DIR/report.md``: the evaluation table, the best model, the paper's claims beside ours.

    python -m jaxlc.evaluation.report RUN_DIR

Reads ``RUN_DIR/eval/eval.json`` (``python -m jaxlc.evaluate``); every number in the report is
computed from the run, the paper's only quoted. With several seeds per grid cell the paper's
claims get a verdict from intervals over seeds (the rules: ``jaxlc.evaluation.stats``).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc.evaluation import stats
from jaxlc.evaluation.results import OUTCOMES, EvalError, rank_models
from jaxlc.evaluation.stats import final_rows
from jaxlc.paper.claims import CLAIM_D, COMPARISONS
from jaxlc.paper.grid import BEST, BEST_TAG, is_best
from jaxlc.study.checkpoint import write_text_atomic
from jaxlc.study.rundir import RunDir

FIGURES = (
    ("fig3_returns.png", "Fig. 3: total reward per training episode"),
    ("fig4_steps_loss.png", "Fig. 4: manoeuvre steps and critic loss"),
    ("fig5_scenes.png", "Fig. 5: scenes at chosen checkpoints"),
    ("fig6_checkpoints.png", "Fig. 6: average return and success rate per checkpoint"),
    ("fig7_trajectories.png", "Fig. 7: lane-change trajectories"),
    ("speed_gaps.png", "Speed and gaps to the target lane's lead and lag over the manoeuvre"),
    ("profiles.png", "Performance profiles: share of models above each success rate"),
    ("learning.gif", "Video: lane changes across checkpoints"),
    ("heldout_norms.png", "Held-out lane changes against the safety and comfort norms"),
)
HUMAN_DURATION = (3.0, 8.0)  # s, the human range docs/results.md compares with


PAPER = f"{BEST_TAG} (k={BEST[0]}, D={BEST[1]})"  # the model the paper finds best


def _defined(v: Any) -> bool:
    return v is not None and v == v


def _pct(v: Any) -> str:
    return f"{100 * v:.1f}%" if _defined(v) else "–"


def _f(v: Any, fmt: str = ".2f") -> str:
    return format(v, fmt) if _defined(v) else "–"


def _table(rows: list[dict[str, Any]]) -> list[str]:
    ends = OUTCOMES[1:] + OUTCOMES[:1]
    lines = [
        "| model | seed | checkpoint | performed | success rate | avg return | "
        + " | ".join(e.replace("_", " ") for e in ends)
        + " | duration (s) | peak lat. acc. (m/s²) | peak yaw rate (rad/s) | overshoot (m) "
        "| timeouts: median final \\|Δd\\| (m) / \\|ψ\\| (rad) / \\|ω\\| (rad/s) |",
        "|---" * (11 + len(ends)) + "|",
    ]
    for r in rows:
        lines.append(
            f"| {r['label']} | {r.get('seed', '') if r['model'] is not None else ''} | "
            f"{r['episode'] or '–'} | {r['performed']}/{r['cases']} | {_pct(r['success_rate'])} "
            f"| {_f(r['avg_return'], '.1f')} | "
            + " | ".join(str(r[e]) for e in ends)
            + f" | {_f(r['duration_s'])} | {_f(r['peak_lat_acc'])} | "
            f"{_f(r['peak_yaw_rate'], '.3f')} | {_f(r['overshoot_m'], '.3f')} | "
            f"{_timeouts(r)} |"
        )
    return lines


def _timeouts(r: dict[str, Any]) -> str:
    keys = ("timeout_offset_m", "timeout_heading", "timeout_yaw_rate")
    if not _defined(r.get(keys[0])):
        return "–"
    return " / ".join(_f(r[k], ".3f") for k in keys)


def _timeout_line(result: dict[str, Any], best: dict[str, Any] | None) -> list[str]:
    """Where the best model's timeouts end, beside the success box."""
    if best is None or not best.get("timeout") or not _defined(best.get("timeout_offset_m")):
        return []
    box = result.get("success_box", {})
    limits = (
        f" (success box: |Δd| ≤ {box['offset_m']:g} m, |ψ| ≤ {box['heading']:g} rad, "
        f"|ω| ≤ {box['yaw_rate']:g} rad/s)"
        if box
        else ""
    )
    return [
        "",
        f"Its {best['timeout']} timeout{'s end' if best['timeout'] > 1 else ' ends'} at a "
        f"median |Δd| of "
        f"{_f(best['timeout_offset_m'], '.3f')} m from the target centre line, |ψ| "
        f"{_f(best['timeout_heading'], '.3f')} rad and |ω| {_f(best['timeout_yaw_rate'], '.3f')} "
        f"rad/s{limits}: a large |Δd| with a small |ω| is stopping short, a large |ω| "
        "oscillating, all three near the box a tight success box.",
    ]


def _best_section(rows: list[dict[str, Any]]) -> tuple[list[str], dict[str, Any] | None]:
    ranked = rank_models(rows)
    if not ranked:
        return ["No model checkpoint was evaluated."], None
    best = ranked[0]
    out = [
        f"**Best model: {best['label']} (model {best['model']}, seed {best['seed']})**, at "
        f"checkpoint {best['episode']}: success rate {_pct(best['success_rate'])} of "
        f"{best['performed']} lane changes, average return {_f(best['avg_return'], '.1f')}."
    ]
    if len(ranked) > 1:
        nxt = ranked[1]
        d_sr = (
            f"{100 * (best['success_rate'] - nxt['success_rate']):+.1f} points"
            if _defined(best["success_rate"]) and _defined(nxt["success_rate"])
            else "undefined"
        )
        d_ret = (
            f"{best['avg_return'] - nxt['avg_return']:+.1f}"
            if _defined(best["avg_return"]) and _defined(nxt["avg_return"])
            else "undefined"
        )
        out.append(
            f"Runner-up: {nxt['label']} (model {nxt['model']}, seed {nxt['seed']}): success "
            f"rate {_pct(nxt['success_rate'])}, average return {_f(nxt['avg_return'], '.1f')}. "
            f"Margin: success rate {d_sr}, average return {d_ret}."
        )
        if best["success_rate"] == nxt["success_rate"]:
            out.append("The success rates tie, so the return decides; treat the ranking as weak.")
    return out, best


def rank_cells(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Grid cells (models that differ only by seed), best first by mean final success rate
    then mean return; each ``{"label", "best", "seeds", "success_rate", "avg_return"}``
    (``best``: the paper's best model, ``paper.grid.is_best``)."""
    groups: dict[str, list[dict[str, Any]]] = {}
    for r in final_rows(rows):
        groups.setdefault(r["label"], []).append(r)

    def mean(rs: list[dict[str, Any]], key: str) -> float:
        vals = [r[key] for r in rs if _defined(r[key])]
        return sum(vals) / len(vals) if vals else math.nan

    cells = [
        {
            "label": k,
            "best": is_best(rs[0]),
            "seeds": len(rs),
            **{m: mean(rs, m) for m in ("success_rate", "avg_return")},
        }
        for k, rs in groups.items()
    ]

    def key(c: dict[str, Any]) -> tuple[float, float]:
        sr, ret = c["success_rate"], c["avg_return"]
        return (sr if _defined(sr) else -1.0, ret if _defined(ret) else -math.inf)

    return sorted(cells, key=key, reverse=True)


def _ci(est: float, lo: float, hi: float, fmt: str, scale: float = 1.0) -> str:
    if not _defined(est):
        return "–"
    text = format(scale * est, fmt)
    if _defined(lo):
        text += f" [{format(scale * lo, fmt)}, {format(scale * hi, fmt)}]"
    return text


def _seed_section(rows: list[dict[str, Any]]) -> list[str]:
    """Each cell's success and return at its last evaluated checkpoint over seeds (means and
    IQMs with intervals), and the probability that each cell improves on each other."""
    cells = stats.cells_of(rows)
    if not cells:
        return []
    n = stats.fewest_seeds(cells)
    note = stats.seeds_note(cells)
    lines = [
        "## Success over seeds",
        "",
        f"{len(cells)} grid cells, {n} seed{'s' * (n != 1)} in the smallest; each model at its "
        "last evaluated checkpoint. Brackets: 95% bootstrap intervals over seeds (resampled "
        "within each cell; `jaxlc.evaluation.stats`).",
    ]
    if note:
        lines += ["", f"**Note: {note}** (train with `--seeds N`)."]
    lines += [
        "",
        "| cell | seeds | success rate, mean | success rate, IQM | avg return, mean | "
        "avg return, IQM |",
        "|---|---|---|---|---|---|",
    ]
    for r in stats.final_table(cells):
        s, ret = (
            [(r[f"{m}_{q}"], r[f"{m}_{q}_lo"], r[f"{m}_{q}_hi"]) for q in ("mean", "iqm")]
            for m in ("success", "return")
        )
        lines.append(
            f"| {r['label']} | {r['seeds']} | {_ci(*s[0], '.1f', 100)}% | "
            f"{_ci(*s[1], '.1f', 100)}% | {_ci(*ret[0], '.1f')} | {_ci(*ret[1], '.1f')} |"
        )
    if len(cells) > 1:
        p = {(r["x"], r["y"]): r for r in stats.improvement_table(cells)}
        tags = [c.label.split()[0] for c in cells]
        lines += [
            "",
            "Probability of improvement P(row > column) of the final success rate over pairs "
            "of seeds (ties count half):",
            "",
            "| | " + " | ".join(tags) + " |",
            "|---" * (len(cells) + 1) + "|",
        ]
        for x, tx in zip(cells, tags, strict=True):
            vals = ["–" if x is y else f"{p[x.label, y.label]['p']:.2f}" for y in cells]
            lines.append(f"| {tx} | " + " | ".join(vals) + " |")
    return lines + [""]


def compare_markdown(table: list[dict[str, Any]], run_a: Path, run_b: Path) -> str:
    """The ``--compare`` table: per cell at the last common checkpoint, mean success rates
    of both runs and B - A with its interval."""
    last = max(r["episode"] for r in table)
    lines = [
        f"# {run_b.name} against {run_a.name}",
        "",
        f"Mean evaluated success rate over seeds per grid cell at checkpoint {last}; B − A "
        "with a 95% bootstrap interval (each run's seeds resampled on their own). A: "
        f"`{run_a}`, B: `{run_b}`. Every checkpoint: `compare.csv`.",
        "",
        "| cell | seeds A | seeds B | success A | success B | B − A (points) |",
        "|---|---|---|---|---|---|",
    ]
    for r in table:
        if r["episode"] == last:
            diff = _ci(r["diff"], r["diff_lo"], r["diff_hi"], "+.1f", 100)
            lines.append(
                f"| {r['label']} | {r['seeds_a']} | {r['seeds_b']} | {_pct(r['success_a'])} | "
                f"{_pct(r['success_b'])} | {diff} |"
            )
    if min(min(r["seeds_a"], r["seeds_b"]) for r in table) < 2:
        lines += ["", f"Note: {stats.SEEDS_NOTE} in each run."]
    lines += ["", "![B − A per cell](compare.png)", ""]
    return "\n".join(lines)


def _claims(result: dict[str, Any], best: dict[str, Any] | None) -> list[str]:
    rows = result["rows"]
    finals = final_rows(rows)
    four = [r for r in finals if is_best(r)]
    scripted = next((r for r in rows if r["model"] is None), None)
    lines = ["| claim | paper | this run | agrees |", "|---|---|---|---|"]

    if best is None:
        return lines
    if four:
        cells = rank_cells(rows)  # with several seeds, a cell's claim is about its mean
        pick = cells[0] if cells[0]["seeds"] > 1 else {**best, "best": is_best(best)}
        top, ok = pick["label"], pick["best"]
        ours = f"{top} is best" + (" (mean over seeds)" if cells[0]["seeds"] > 1 else "")
        lines.append(f"| best model | {PAPER} | {ours} | {'yes' if ok else 'no'} |")
    else:
        lines.append(f"| best model | {PAPER} | the grid has no model {BEST_TAG} | n/a |")

    others = [(f"model {BEST_TAG}, seed {r['seed']}", r) for r in four if r is not best]
    for who, r in [("best model", best), *others]:
        sr = r["success_rate"]
        ok = "yes" if _defined(sr) and sr == 1.0 else "no"
        lines.append(
            f"| success rate at the final checkpoint, over cases with a lane change ({who}) "
            f"| 100% | {_pct(sr)} ({r['success']} of {r['performed']}; "
            f"{r['out_of_bounds']} out of bounds, {r['collision']} collisions, "
            f"{r['timeout']} timeouts) | {ok} |"
        )
    n, perf = result["cases"], result["performed"]
    close = abs(perf / n - 0.8) <= 0.1
    lines.append(
        f"| cases that performed a lane change (agrees: within ±10 points) | 80 of 100 | "
        f"{perf} of {n} ({100 * perf / n:.0f}%) | {'yes' if close else 'no'} |"
    )
    mine = sorted((r for r in rows if r["model"] == best["model"]), key=lambda r: r["episode"])
    first, last = mine[0], mine[-1]
    rose = _defined(first["avg_return"]) and _defined(last["avg_return"])
    rose = rose and last["avg_return"] > first["avg_return"]
    lines.append(
        f"| average return rises over checkpoints, then plateaus (Fig. 6) | from −20 (a "
        f"default for no lane change) | {_f(first['avg_return'], '.1f')} at checkpoint "
        f"{first['episode']} → {_f(last['avg_return'], '.1f')} at {last['episode']} (raw "
        f"returns; eq. (11) cannot give −20) | {'rises' if rose else 'does not rise'} |"
    )
    d = best["duration_s"]
    in_range = _defined(d) and HUMAN_DURATION[0] <= d <= HUMAN_DURATION[1]
    ref = f"; scripted controller {_f(scripted['duration_s'])} s" if scripted else ""
    ours = f"{_f(d)} s" if _defined(d) else "no successful lane change"
    lines.append(
        f"| lane-change duration like a human's | humans 3–8 s (mean ≈ 6 s) | "
        f"{ours} (best model, successful cases{ref}) | {'yes' if in_range else 'no'} |"
    )
    return lines


def _heldout_tables(doc: dict[str, Any]) -> list[str]:
    """Per cell and per model: outcomes with intervals, then the norms."""
    lines = [
        "| cell | seeds | lane changes | success, mean [interval] | failures | failure "
        "< (95%) | collisions | collision rate | inside every norm |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in doc["cells"]:
        ci = f"{_pct(c['success_mean'])} [{_pct(c['success_lo'])}, {_pct(c['success_hi'])}]"
        lines.append(
            f"| {c['label']} | {c['seeds']} | {c['lane_changes']} | {ci} | {c['failures']} | "
            f"{_f(100 * c['failure_bound'])}% | {c['collisions']} | "
            f"{_f(100 * c['collision_rate'], '.2f')}% | {_pct(c['norm_all'])} |"
        )
    how = sorted({c["interval"] for c in doc["cells"]})
    lines += ["", f"Cell intervals: {'; '.join(how)}.", ""]
    norms = [n["measure"] for n in doc["norms"]]
    lines += [
        "| model | seed | success [95% CP] | out of bounds | collision | timeout | "
        "duration s | R79 manoeuvre s | peak lat. acc. m/s² | peak lat. jerk m/s³ | "
        "peak long. acc. m/s² | peak long. jerk m/s³ | min TTC s, 5th pct. | "
        "min THW s, 5th pct. | " + " | ".join(f"{m} ok" for m in norms) + " | all norms |",
        "|---" * (15 + len(norms)) + "|",
    ]
    for r in doc["rows"]:
        lines.append(
            f"| {r['label']} | {'' if r['seed'] is None else r['seed']} | "
            f"{_pct(r['success_rate'])} [{_pct(r['success_lo'])}, {_pct(r['success_hi'])}] "
            f"| {r['out_of_bounds']} | {r['collision']} | {r['timeout']} | "
            f"{_f(r['duration_s'])} | {_f(r.get('lcm_s'))} | {_f(r['peak_lat_acc'])} | "
            f"{_f(r['peak_lat_jerk'])} | {_f(r.get('peak_long_acc'))} | "
            f"{_f(r.get('peak_long_jerk'))} | "
            f"{_tail(r, 'min_ttc_s')} | {_tail(r, 'min_thw_s')} | "
            + " | ".join(_pct(r[f"norm_{m}"]) for m in norms)
            + f" | {_pct(r['norm_all'])} |"
        )
    return lines


def _tail(r: dict[str, Any], key: str) -> str:
    """A TTC or headway percentile; JSON holds an infinite one (no closing) as null."""
    return "∞" if r[key] is None and r["lane_changes"] else _f(r[key])


def _collision_tally(doc: dict[str, Any]) -> list[str]:
    hits = doc["collisions"]
    if not hits:
        return ["No held-out lane change of any policy ended in a collision.", ""]
    hazards = any("hazard" in h for h in hits)  # evaluated where the traffic has hazards
    groups: dict[tuple[str, str, bool], list[dict[str, Any]]] = {}
    for h in hits:
        groups.setdefault((h["partner"], h.get("hazard", ""), h["yielding"]), []).append(h)
    lines = [
        f"{len(hits)} collisions. By the vehicle hit"
        + (", what it was doing" if hazards else "")
        + " and whether the target lane's lag was drawn yielding (medians):",
        "",
        "| vehicle hit |"
        + (" it was |" if hazards else "")
        + " lag yields | collisions | ego speed m/s | time into manoeuvre s | "
        "lag gap at acceptance m | lag speed at acceptance m/s | ego speed at acceptance m/s |",
        "|---|---|---|---|---|---|---|---|" + ("---|" if hazards else ""),
    ]
    for (who, hz, ylds), hs in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        med = {k: _median([h[k] for h in hs]) for k in COLLISION_MEDIANS}
        lines.append(
            f"| {who.replace('_', ' ')} | "
            + (f"{hz.replace('_', ' ')} | " if hazards else "")
            + f"{'yes' if ylds else 'no'} | {len(hs)} | "
            + " | ".join(_f(med[k], ".1f") for k in COLLISION_MEDIANS)
            + " |"
        )
    return lines + [
        "",
        "– : no collision of the row had that value (the target lane had no lag vehicle when "
        "the gap was accepted). Every collision: `eval/collisions.csv`.",
        "",
    ]


def _median(values: list[Any]) -> float:
    """Median of the defined values (a record holds None where there was no such vehicle);
    NaN, printed as a dash, when none is."""
    kept = [float(v) for v in values if _defined(v)]
    return float(np.median(kept)) if kept else math.nan


# How a held-out file written before safety.COUNTED counted headway and TTC.
EVERY_STEP = "on every step from the manoeuvre's start"
COLLISION_MEDIANS = ("hit_speed", "time_s", "accept_lag_gap", "accept_lag_v", "accept_v")


def _heldout_section(doc: dict[str, Any] | None, tag: str = "") -> list[str]:
    """``eval/heldout.json``'s content (``doc``; None: the run has no held-out evaluation),
    or that of ``eval/heldout_TAG/heldout.json``, driven in another traffic."""
    if doc is None:
        return []
    norms = "; ".join(n["source"] for n in doc["norms"])
    d = doc["claim_d"]
    where = f" in another traffic (`{tag}`)" if tag else ""
    overrides = ", ".join(f"`{o}`" for o in doc.get("traffic_overrides", []))
    return [
        f"## Held-out lane changes{where}",
        "",
        f"Measured in {doc.get('traffic', 'the training traffic')}"
        + (f" (overrides {overrides})." if overrides else ".")
        + (
            " Cut-ins met and braking events of the vehicles around the ego are counted per "
            "lane change (`cut_ins`, `met_cut_in`, `brakes_near`, `met_braking` in "
            "`heldout.csv`); each collision names what the vehicle hit was doing."
            if overrides
            else ""
        ),
        "",
        f"Each model's final checkpoint and the scripted controller on {doc['lane_changes']} "
        f"held-out lane changes ({doc['cases']} cases of `{doc['key_stream']}`, a key stream "
        "apart from the protocol's cases and from training), no noise. Per model: two-sided "
        "95% Clopper-Pearson intervals, and `failure <`, the one-sided 95% upper bound on "
        f"the failure rate. The norms, per lane change: {norms}. A lane change is inside "
        "every norm when it succeeds and meets all of them; TTC and time headway are the "
        "minimum over the manoeuvre of those to the target lane's lead and lag and the own "
        f"lane's leader, counted {doc.get('conflicts_counted', EVERY_STEP)} "
        "(`jaxlc.evaluation.safety`); the table gives their 5th "
        "percentile over the lane changes, ∞ where fewer than 5% close in. Figure: "
        "[heldout_norms.png](figures/heldout_norms.png).",
        "",
        f"**Claim (d)**: {d['figures']}: **{d['verdict']}** (supported when the bound is at "
        "most 1%).",
        "",
        *_heldout_tables(doc),
        "",
        "### Collisions",
        "",
        *_collision_tally(doc),
    ]


def _claim_d(held: dict[str, Any] | None) -> dict[str, str]:
    """Claim (d) as the README's verdict decides it, on the held-out lane changes
    (``heldout.claim_d``); named even where the run was evaluated without them."""
    if held is not None:
        return {**held["claim_d"], "measures": "held-out failures"}
    figures = "needs the held-out lane changes (evaluate with --lane-changes above 0)"
    return {"claim": CLAIM_D, "measures": "held-out failures", "figures": figures, "verdict": "n/a"}


def _claims_section(run_dir: Path, held: dict[str, Any] | None) -> list[str]:
    """The paper's claims (``jaxlc.paper.claims``), the same as README.md's verdict: (a)-(c)
    on learning speed (``jaxlc.evaluation.convergence``), (d) on the held-out lane changes."""
    path = RunDir(run_dir).convergence
    doc = json.loads(path.read_text()) if path.is_file() else None
    d = _claim_d(held)
    lines = ["## The paper's claims", ""]
    if doc is None:
        lines += [
            "(a)–(c) need the training curves (`metrics/episodes.npz`), which this run lacks.",
            "",
        ]
        waiting = "needs the training curves (`metrics/episodes.npz`)"
        doc = {
            "claims": [
                {"claim": c, "measures": ", ".join(keys), "figures": waiting, "verdict": "n/a"}
                for c, _, keys in COMPARISONS
            ],
            "models": [],
        }
    else:
        lines += [
            "The paper argues (a)–(c) from its training curves (Figs. 3, 4), so they are decided "
            "here on measures of each model's training curves (noise on; "
            "`jaxlc.evaluation.convergence`): "
            f"`converged`, the episode from which the return's {doc['window']}-episode moving "
            f"average stays within {100 * doc['band']:.0f}% of its rise from its plateau (the mean "
            f"of the last {doc['plateau_episodes']} episodes); `success95`, the first episode with "
            "95% success over the last 100; `steps_rise`, where Fig. 4a's manoeuvre steps reach "
            "half their rise; `auc`, the area under the return curve normalised over the run; "
            '`plateau`, the final return. Each comparison "X better than Y" is decided on how '
            "far X is ahead of Y (the difference of the cells' means over seeds, positive on the "
            "paper's side: fewer episodes, more area or return) with its 95% bootstrap interval: "
            "*holds* above zero, *fails* below, *no practical difference* inside the margin "
            f"(±{100 * doc.get('margin_share', 0.02):.0f}% of the measure's axis: training "
            "episodes, the run's return range), undecided otherwise, and always below 5 seeds per "
            "cell.",
            "",
        ]
    lines += ["| claim | key measures | this run | verdict |", "|---|---|---|---|"]
    for c in [*doc["claims"], d]:
        lines.append(f"| {c['claim']} | {c['measures']} | {c['figures']} | **{c['verdict']}** |")
    if not doc["models"]:
        return lines + [""]
    lines += ["", "| model | seed | " + " | ".join(MEASURE_NAMES) + " |"]
    lines.append("|---" * (2 + len(MEASURE_NAMES)) + "|")
    for m in doc["models"]:
        vals = [_f(m[k], ".0f") for k in MEASURE_NAMES[:3]] + [
            _f(m["auc"], ".3f"),
            _f(m["plateau"], ".1f"),
        ]
        lines.append(f"| {m['label']} | {m['seed']} | " + " | ".join(vals) + " |")
    return lines + ["", "Every comparison on every measure: `eval/convergence.json`.", ""]


MEASURE_NAMES = ("converged", "success95", "steps_rise", "auc", "plateau")


def _validation_section(run_dir: Path) -> list[str]:
    """``python -m jaxlc.validate``'s section, where the run was validated."""
    from jaxlc.evaluation.validation_io import report_section

    return report_section(run_dir)


def build_report(run_dir: Path) -> str:
    """The report's Markdown for ``run_dir`` (needs ``eval/eval.json``)."""
    path = RunDir(run_dir).eval_json
    if not path.is_file():
        raise EvalError(f"{path} is missing; run python -m jaxlc.evaluate {run_dir} first")
    result = json.loads(path.read_text())
    rows = result["rows"]
    best_lines, best = _best_section(rows)
    held_path = RunDir(run_dir).heldout_json
    held = json.loads(held_path.read_text()) if held_path.is_file() else None
    early = result["before_rl"]
    text = [
        f"# Evaluation report: {run_dir.name}",
        "",
        f"{result['cases']} lane-change cases (seed {result['seed']}, step cap "
        f"{result['max_steps']}), the same for every checkpoint, no exploration noise. "
        f"{result['performed']} cases reached the RL phase ({result['left']} left, "
        f"{result['right']} right lane changes); of the others, {early['no_gap']} found no "
        f"acceptable gap, {early['collision']} collided before the lane change and "
        f"{early['unfinished']} hit the step cap (the same for every policy: the action only "
        "acts in the RL phase). Success rate and average return are over the cases "
        "with a lane change; duration, peak lateral acceleration (|v·ω|), peak yaw rate and "
        "overshoot past the target centre line are means over the successful ones. Outcome "
        "counts add up to the cases. Config hash "
        f"`{result['config_hash']}`.",
        "",
        "## Best model",
        "",
        *best_lines,
        *_timeout_line(result, best),
        "",
        *_claims_section(run_dir, held),
        *_heldout_section(held),
        *[
            line
            for path in sorted(RunDir(run_dir).eval.glob("heldout_*/heldout.json"))
            for line in _heldout_section(json.loads(path.read_text()), path.parent.name[8:])
        ],
        *_validation_section(run_dir),
        *_seed_section(rows),
        "## The paper's other figures beside this run",
        "",
        *_claims(result, best),
        "",
        "## Every model and checkpoint",
        "",
        *_table(rows),
        "",
    ]
    made = [(f, t) for f, t in FIGURES if RunDir(run_dir).figure(f).is_file()]
    if made:
        text += ["## Figures", ""] + [f"- [{t}](figures/{f})" for f, t in made] + [""]
    return "\n".join(text)


def write_report(run_dir: Path) -> Path:
    """Write ``run_dir/report.md`` atomically; returns its path."""
    run_dir = Path(run_dir)
    return write_text_atomic(RunDir(run_dir).report, build_report(run_dir))


def main(argv: list[str] | None = None) -> int:
    args = argv if argv is not None else sys.argv[1:]
    if len(args) != 1:
        print("usage: python -m jaxlc.evaluation.report RUN_DIR", file=sys.stderr)
        return 2
    try:
        print(write_report(Path(args[0])))
    except EvalError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
