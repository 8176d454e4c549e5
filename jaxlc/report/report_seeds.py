"""``report.md``'s section over seeds (each cell's success and return with intervals, the
probability that one cell improves on another) and ``compare.md``, two runs side by side
(the statistics: ``jaxlc.evaluation.stats``)."""

from __future__ import annotations

from pathlib import Path

from jaxlc.evaluation import stats
from jaxlc.evaluation.numbers import read, write_csv
from jaxlc.evaluation.results import EvalError, EvalResult, Row
from jaxlc.report import report_text as text
from jaxlc.report.report_text import interval, percent
from jaxlc.study.checkpoint import write_text_atomic
from jaxlc.study.rundir import RunDir


def section(rows: list[Row]) -> list[str]:
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
        text.SEEDS.format(cells=len(cells), n=n, s="s" * (n != 1)),
    ]
    if note:
        lines += ["", text.SEEDS_NOTE.format(note=note)]
    lines += [
        "",
        "| cell | seeds | success rate, mean | success rate, IQM | avg return, mean | "
        "avg return, IQM |",
        "|---|---|---|---|---|---|",
    ]
    for r in stats.final_table(cells):
        lines.append(
            f"| {r.label} | {r.seeds} | "
            f"{interval(r.success_mean, r.success_mean_lo, r.success_mean_hi, '.1f', 100)}% | "
            f"{interval(r.success_iqm, r.success_iqm_lo, r.success_iqm_hi, '.1f', 100)}% | "
            f"{interval(r.return_mean, r.return_mean_lo, r.return_mean_hi, '.1f')} | "
            f"{interval(r.return_iqm, r.return_iqm_lo, r.return_iqm_hi, '.1f')} |"
        )
    if len(cells) > 1:
        p = {(r.x, r.y): r.p for r in stats.improvement_table(cells)}
        tags = [c.label.split()[0] for c in cells]
        lines += [
            "",
            text.IMPROVEMENT,
            "",
            "| | " + " | ".join(tags) + " |",
            "|---" * (len(cells) + 1) + "|",
        ]
        for x, tx in zip(cells, tags, strict=True):
            vals = ["–" if x is y else f"{p[x.label, y.label]:.2f}" for y in cells]
            lines.append(f"| {tx} | " + " | ".join(vals) + " |")
    return lines + [""]


def compare_markdown(table: list[stats.Difference], run_a: Path, run_b: Path) -> str:
    """The ``--compare`` table: per cell at the last common checkpoint, mean success rates
    of both runs and B - A with its interval."""
    last = max(r.episode for r in table)
    lines = [
        f"# {run_b.name} against {run_a.name}",
        "",
        text.COMPARE.format(last=last, run_a=run_a, run_b=run_b),
        "",
        "| cell | seeds A | seeds B | success A | success B | B − A (points) |",
        "|---|---|---|---|---|---|",
    ]
    for r in table:
        if r.episode == last:
            diff = interval(r.diff, r.diff_lo, r.diff_hi, "+.1f", 100)
            lines.append(
                f"| {r.label} | {r.seeds_a} | {r.seeds_b} | {percent(r.success_a)} | "
                f"{percent(r.success_b)} | {diff} |"
            )
    if min(min(r.seeds_a, r.seeds_b) for r in table) < 2:
        lines += ["", text.COMPARE_NOTE.format(note=stats.SEEDS_NOTE)]
    lines += ["", "![B − A per cell](compare.png)", ""]
    return "\n".join(lines)


def _eval_rows(run_dir: Path) -> list[Row]:
    path = RunDir(run_dir).eval_json
    if not path.is_file():
        raise EvalError(f"{path} is missing; run python -m jaxlc.evaluate {run_dir} first")
    return read(path, EvalResult).rows


def compare_runs(run_a: Path, run_b: Path, out: Path | None = None) -> Path:
    """Per-cell differences B - A of the mean success rate of two evaluated runs (their
    ``eval/eval.json``; nothing is re-evaluated): writes ``compare.md``, ``compare.csv`` and
    ``compare.png`` into ``out`` (default ``run_b/compare_<name of run_a>``); returns it."""
    from jaxlc.report import plots

    run_a, run_b = Path(run_a), Path(run_b)
    table = stats.compare(stats.cells_of(_eval_rows(run_a)), stats.cells_of(_eval_rows(run_b)))
    out = Path(out) if out is not None else run_b / f"compare_{run_a.resolve().name}"
    out.mkdir(parents=True, exist_ok=True)
    write_csv(out / "compare.csv", table)
    plots.fig_compare(table, run_a.name, run_b.name, out / "compare.png")
    write_text_atomic(out / "compare.md", compare_markdown(table, run_a, run_b))
    return out
