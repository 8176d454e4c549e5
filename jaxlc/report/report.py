"""``RUN_DIR/report.md``: the evaluation table, the best model, the paper's claims beside ours.

    python -m jaxlc.report.report RUN_DIR

Reads ``RUN_DIR/eval/eval.json`` (``python -m jaxlc.evaluate``); every number in the report is
computed from the run, the paper's only quoted. The prose around the numbers is
``jaxlc.report.report_text``'s. With several seeds per grid cell the paper's
claims get a verdict from intervals over seeds (the rules: ``jaxlc.evaluation.stats``).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from jaxlc.evaluation.convergence import Convergence
from jaxlc.evaluation.numbers import defined, fixed, read
from jaxlc.evaluation.results import (
    OUTCOMES,
    Claim,
    EvalError,
    EvalResult,
    Heldout,
    Row,
    final_rows,
    rank_key,
    rank_models,
)
from jaxlc.paper.claims import CLAIM_D, COMPARISONS
from jaxlc.paper.grid import BEST, BEST_TAG, is_best
from jaxlc.report import report_heldout, report_seeds
from jaxlc.report import report_text as text
from jaxlc.report.report_text import EVERY_STEP, percent  # noqa: F401  (benchmarks/tables reads EVERY_STEP)
from jaxlc.study.checkpoint import write_text_atomic
from jaxlc.study.rundir import RunDir

HUMAN_DURATION = (3.0, 8.0)  # s, the human range docs/results.md compares with
BEST_LABEL = f"{BEST_TAG} (k={BEST[0]}, D={BEST[1]})"  # the model the paper finds best
MEASURE_NAMES = ("converged", "success95", "steps_rise", "auc", "plateau")


def _table(rows: list[Row]) -> list[str]:
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
            f"| {r.label} | {r.seed if r.model is not None else ''} | "
            f"{r.episode or '–'} | {r.performed}/{r.cases} | {percent(r.success_rate)} "
            f"| {fixed(r.avg_return, '.1f')} | "
            + " | ".join(str(getattr(r, e)) for e in ends)
            + f" | {fixed(r.duration_s)} | {fixed(r.peak_lat_acc)} | "
            f"{fixed(r.peak_yaw_rate, '.3f')} | {fixed(r.overshoot_m, '.3f')} | "
            f"{_timeouts(r)} |"
        )
    return lines


def _timeouts(r: Row) -> str:
    if not defined(r.timeout_offset_m):
        return "–"
    return " / ".join(fixed(v, ".3f") for v in _ends(r))


def _ends(r: Row) -> tuple[Any, ...]:
    return r.timeout_offset_m, r.timeout_heading, r.timeout_yaw_rate


def _timeout_line(result: EvalResult, best: Row | None) -> list[str]:
    """Where the best model's timeouts end, beside the success box."""
    if best is None or not best.timeout or not defined(best.timeout_offset_m):
        return []
    box = result.success_box
    offset, heading, yaw_rate = (fixed(v, ".3f") for v in _ends(best))
    line = text.TIMEOUTS.format(
        n=best.timeout,
        ends="s end" if best.timeout > 1 else " ends",
        offset=offset,
        heading=heading,
        yaw_rate=yaw_rate,
        box=text.SUCCESS_BOX.format(**box) if box else "",
    )
    return ["", line]


def _best_section(rows: list[Row]) -> tuple[list[str], Row | None]:
    ranked = rank_models(rows)
    if not ranked:
        return [text.NO_MODEL], None
    best = ranked[0]
    out = [
        text.BEST.format(
            **best.as_dict(), rate=percent(best.success_rate), ret=fixed(best.avg_return, ".1f")
        )
    ]
    if len(ranked) > 1:
        nxt = ranked[1]
        d_sr = (
            f"{100 * (best.success_rate - nxt.success_rate):+.1f} points"
            if defined(best.success_rate) and defined(nxt.success_rate)
            else "undefined"
        )
        d_ret = (
            f"{best.avg_return - nxt.avg_return:+.1f}"
            if defined(best.avg_return) and defined(nxt.avg_return)
            else "undefined"
        )
        out.append(
            text.RUNNER_UP.format(
                **nxt.as_dict(),
                rate=percent(nxt.success_rate),
                ret=fixed(nxt.avg_return, ".1f"),
                d_rate=d_sr,
                d_ret=d_ret,
            )
        )
        if best.success_rate == nxt.success_rate:
            out.append(text.TIE)
    return out, best


@dataclass
class Ranked:
    """A grid cell (models that differ only by seed) by its mean final success rate, then
    mean return; ``best``: the paper's best model (``paper.grid.is_best``)."""

    label: str
    best: bool
    seeds: int
    success_rate: float
    avg_return: float


def rank_cells(rows: list[Row]) -> list[Ranked]:
    """Grid cells, best first."""
    groups: dict[str, list[Row]] = {}
    for r in final_rows(rows):
        groups.setdefault(r.label, []).append(r)

    def mean(values: list[Any]) -> float:
        vals = [v for v in values if defined(v)]
        return sum(vals) / len(vals) if vals else math.nan

    cells = [
        Ranked(
            k,
            is_best(rs[0]),
            len(rs),
            mean([r.success_rate for r in rs]),
            mean([r.avg_return for r in rs]),
        )
        for k, rs in groups.items()
    ]
    return sorted(cells, key=rank_key, reverse=True)


def _claims(result: EvalResult, best: Row | None) -> list[str]:
    rows = result.rows
    finals = final_rows(rows)
    four = [r for r in finals if is_best(r)]
    scripted = next((r for r in rows if r.model is None), None)
    lines = ["| claim | paper | this run | agrees |", "|---|---|---|---|"]

    if best is None:
        return lines
    if four:
        cells = rank_cells(rows)  # with several seeds, a cell's claim is about its mean
        several = cells[0].seeds > 1
        top, ok = (cells[0].label, cells[0].best) if several else (best.label, is_best(best))
        ours = f"{top} is best" + (" (mean over seeds)" if several else "")
        agrees = "yes" if ok else "no"
    else:
        ours, agrees = f"the grid has no model {BEST_TAG}", "n/a"
    lines.append(text.CLAIM_BEST.format(paper=BEST_LABEL, ours=ours, agrees=agrees))

    others = [(f"model {BEST_TAG}, seed {r.seed}", r) for r in four if r is not best]
    for who, r in [("best model", best), *others]:
        sr = r.success_rate
        ok = "yes" if defined(sr) and sr == 1.0 else "no"
        lines.append(
            text.CLAIM_SUCCESS.format(
                who=who,
                success=percent(sr),
                n_success=r.success,
                performed=r.performed,
                out_of_bounds=r.out_of_bounds,
                collision=r.collision,
                timeout=r.timeout,
                agrees=ok,
            )
        )
    n, perf = result.cases, result.performed
    close = abs(perf / n - 0.8) <= 0.1
    lines.append(
        text.CLAIM_PERFORMED.format(
            performed=perf, cases=n, share=100 * perf / n, agrees="yes" if close else "no"
        )
    )
    mine = sorted((r for r in rows if r.model == best.model), key=lambda r: r.episode)
    first, last = mine[0], mine[-1]
    rose = defined(first.avg_return) and defined(last.avg_return)
    rose = rose and last.avg_return > first.avg_return
    lines.append(
        text.CLAIM_RETURN.format(
            first=fixed(first.avg_return, ".1f"),
            first_episode=first.episode,
            last=fixed(last.avg_return, ".1f"),
            last_episode=last.episode,
            rises="rises" if rose else "does not rise",
        )
    )
    d = best.duration_s
    in_range = defined(d) and HUMAN_DURATION[0] <= d <= HUMAN_DURATION[1]
    ref = f"; scripted controller {fixed(scripted.duration_s)} s" if scripted else ""
    ours = f"{fixed(d)} s" if defined(d) else "no successful lane change"
    lines.append(
        text.CLAIM_DURATION.format(ours=ours, scripted=ref, agrees="yes" if in_range else "no")
    )
    return lines


def _claims_section(run_dir: Path, held: Heldout | None) -> list[str]:
    """The paper's claims (``jaxlc.paper.claims``), the same as README.md's verdict: (a)-(c)
    on learning speed (``jaxlc.evaluation.convergence``), (d) on the held-out lane changes
    (named even where the run was evaluated without them)."""
    path = RunDir(run_dir).convergence
    d = held.claim_d.figures if held is not None else text.CLAIM_D_MISSING
    d_verdict = held.claim_d.verdict if held is not None else "n/a"
    lines = ["## The paper's claims", ""]
    if not path.is_file():
        lines += [text.NO_CURVES, ""]
        waiting = text.WAITING_FOR_CURVES
        doc = Convergence(
            claims=[Claim(c, None, ", ".join(keys), waiting) for c, _, keys in COMPARISONS]
        )
    else:
        doc = read(path, Convergence)
        lines += [
            text.CURVE_MEASURES.format(
                window=doc.window,
                band=100 * doc.band,
                plateau_episodes=doc.plateau_episodes,
                margin=100 * (doc.margin_share or 0.02),
            ),
            "",
        ]
    lines += ["| claim | key measures | this run | verdict |", "|---|---|---|---|"]
    for c in [*doc.claims, Claim(CLAIM_D, None, "held-out failures", d, d_verdict)]:
        lines.append(f"| {c.claim} | {c.measures} | {c.figures} | **{c.verdict}** |")
    if not doc.models:
        return lines + [""]
    lines += ["", "| model | seed | " + " | ".join(MEASURE_NAMES) + " |"]
    lines.append("|---" * (2 + len(MEASURE_NAMES)) + "|")
    for m in doc.models:
        vals = [fixed(getattr(m, k), ".0f") for k in MEASURE_NAMES[:3]]
        vals += [fixed(m.auc, ".3f"), fixed(m.plateau, ".1f")]
        lines.append(f"| {m.label} | {m.seed} | " + " | ".join(vals) + " |")
    return lines + ["", text.CONVERGENCE_FOOTNOTE, ""]


def build_report(run_dir: Path) -> str:
    """The report's Markdown for ``run_dir`` (needs ``eval/eval.json``)."""
    path = RunDir(run_dir).eval_json
    if not path.is_file():
        raise EvalError(f"{path} is missing; run python -m jaxlc.evaluate {run_dir} first")
    result = read(path, EvalResult)
    rows = result.rows
    best_lines, best = _best_section(rows)
    held_path = RunDir(run_dir).heldout_json
    held = read(held_path, Heldout) if held_path.is_file() else None
    lines = [
        f"# Evaluation report: {run_dir.name}",
        "",
        text.INTRO.format(**{**result.as_dict(), **result.before_rl}),
        "",
        "## Best model",
        "",
        *best_lines,
        *_timeout_line(result, best),
        "",
        *_claims_section(run_dir, held),
        *report_heldout.section(held),
        *[
            line
            for path in sorted(RunDir(run_dir).eval.glob("heldout_*/heldout.json"))
            for line in report_heldout.section(read(path, Heldout), path.parent.name[8:])
        ],
        *report_heldout.validation_section(run_dir),
        *report_heldout.ams_section(run_dir),
        *report_seeds.section(rows),
        "## The paper's other figures beside this run",
        "",
        *_claims(result, best),
        "",
        "## Every model and checkpoint",
        "",
        *_table(rows),
        "",
    ]
    made = [(f, t) for f, t in text.FIGURES if RunDir(run_dir).figure(f).is_file()]
    if made:
        lines += ["## Figures", ""] + [f"- [{t}](figures/{f})" for f, t in made] + [""]
    return "\n".join(lines)


def write_report(run_dir: Path) -> Path:
    """Write ``run_dir/report.md`` atomically; returns its path."""
    run_dir = Path(run_dir)
    return write_text_atomic(RunDir(run_dir).report, build_report(run_dir))


def main(argv: list[str] | None = None) -> int:
    args = argv if argv is not None else sys.argv[1:]
    if len(args) != 1:
        print("usage: python -m jaxlc.report.report RUN_DIR", file=sys.stderr)
        return 2
    try:
        print(write_report(Path(args[0])))
    except EvalError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
