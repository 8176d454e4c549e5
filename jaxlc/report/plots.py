"""The paper's figures from a run directory, as PNGs in ``RUN_DIR/figures/`` (Agg backend;
``python -m jaxlc.figures RUN_DIR`` and ``jaxlc-figures`` are its command line).

Fig. 3 total reward per training episode by model group; Fig. 4 manoeuvre steps per episode
and critic loss per training step; Fig. 5 scenes at chosen checkpoints; Fig. 6 average
return (and success rate) per checkpoint; Fig. 7 lane-change trajectories; and
``learning.gif``, lane changes across checkpoints (the paper's video of the learning
progress); ``profiles.png``, performance profiles (share of models above each success rate)
by k. Training figures read ``metrics/`` and ``summary.json``; the others read ``eval/``
(``python -m jaxlc.evaluate``). A figure whose data is missing is skipped. With several
seeds per grid cell a line is the mean over seeds and its band the 95% bootstrap interval
of that mean (``jaxlc.evaluation.stats``).

Returns span -2000 (out of bounds, eq. (11)) to about -100 (a smooth lane change): when a
plot's returns span more than a decade its axis is symlog (linear near zero, log beyond).
Model colours: the paper's for its nine models (``jaxlc.paper.grid``), found by (k, memory).
"""

from __future__ import annotations

import json
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from matplotlib.ticker import FuncFormatter, SymmetricalLogLocator

from jaxlc.evaluation import ams, heldout, stats
from jaxlc.evaluation.convergence import moving
from jaxlc.evaluation.numbers import number, read
from jaxlc.evaluation.results import EvalResult, Heldout
from jaxlc.paper import grid as paper_grid
from jaxlc.report import plots_scenes as scenes
from jaxlc.report.plots_scenes import eval_files as _eval
from jaxlc.report.plots_scenes import npz as _npz
from jaxlc.report.plots_scenes import plt
from jaxlc.report.plots_scenes import save as _save
from jaxlc.study.rundir import RunDir

BAND_POINTS = 300  # bootstrap a training curve's band at this many points, not every episode


# --------------------------------------------------------------------------- data


def _cells(run_dir: Path) -> list[dict[str, Any]] | None:
    """Grid cells of the run with their model indices (one per seed) and paper tag."""
    path = RunDir(run_dir).summary_json
    if not path.is_file():
        return None
    cells: dict[int, dict[str, Any]] = {}
    for m in json.loads(path.read_text())["models"]:
        c = cells.setdefault(
            m["cell"], {"label": m["label"], "models": [], "tag": paper_grid.tag_of(m), "meta": m}
        )
        c["models"].append(m["model"])
    return [cells[c] for c in sorted(cells)]


def _colour(model: Mapping[str, Any], i: int) -> str:
    """The paper's colour for its nine models (``model``: a cell, model or row with ``k`` and
    ``memory``, tagged by ``paper.grid.tag_of``), else cycle."""
    return paper_grid.COLOURS.get(paper_grid.tag_of(model) or "", f"C{i % 10}")


def _window(n: int) -> int:
    return max(1, min(100, n // 20))  # 100 episodes for the paper's 5000, a few for smoke


def _seed_curves(ax: Any, series: list[np.ndarray], colour: str, label: str) -> None:
    """Mean over seeds as a line, the bootstrap interval of that mean as a band (when
    several seeds)."""
    n = min(len(s) for s in series)
    if n == 0:
        return
    w = _window(n)
    curves = np.stack([moving(s[:n].astype(float), w) for s in series])
    x = np.arange(w, n + 1)
    with warnings.catch_warnings():  # all-NaN columns (no loss before updates start)
        warnings.simplefilter("ignore", RuntimeWarning)
        mean = np.nanmean(curves, axis=0)
    ax.plot(x, mean, color=colour, lw=1.4, label=label)
    if len(series) > 1:
        at = np.unique(np.linspace(0, len(x) - 1, min(len(x), BAND_POINTS)).astype(int))
        lo, hi = stats.mean_band(curves[:, at])
        ax.fill_between(x[at], lo, hi, color=colour, alpha=0.2, lw=0)


def _return_axis(ax: Any) -> None:
    """Symlog when the plotted returns span more than a decade (else its ticks vanish)."""
    ys = np.concatenate([np.asarray(line.get_ydata(), float) for line in ax.get_lines()] or [[]])
    mags = np.abs(ys[np.isfinite(ys)])
    if mags.size and mags.max() > 10 * max(mags.min(), 10.0):
        ax.set_yscale("symlog", linthresh=10)
        # Decades alone leave one or two labelled ticks over -2000..-100; add 2x and 5x.
        ax.yaxis.set_major_locator(SymmetricalLogLocator(linthresh=10, base=10, subs=[1, 2, 5]))
        ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))


# --------------------------------------------------------------------------- training


def fig3_returns(run_dir: Path) -> Path | None:
    """Total reward per training episode, smoothed, by the paper's model groups."""
    cells, eps = _cells(run_dir), _npz(RunDir(run_dir).episodes)
    if cells is None or eps is None:
        return None
    by_tag = {c["tag"]: c for c in cells if c["tag"]}
    paper = all(t in by_tag for _, tags in paper_grid.GROUPS for t in tags)
    panels = (
        [(t, [by_tag[x] for x in tags]) for t, tags in paper_grid.GROUPS]
        if paper
        else [("", cells)]
    )
    shape = (2, 2) if paper else (1, 1)
    fig, axes = plt.subplots(
        *shape, figsize=(11, 7) if paper else (7, 4), squeeze=False, layout="constrained"
    )
    for ax, (title, group) in zip(axes.flat, panels, strict=True):
        for i, c in enumerate(group):
            series = [eps["ret"][m, : eps["episodes"][m]] for m in c["models"]]
            _seed_curves(ax, series, _colour(c["meta"], i), c["label"])
        ax.set(title=title, xlabel="training episode", ylabel="total reward")
        _return_axis(ax)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle(
        "Fig. 3  Total reward per training episode (moving average; band: 95% interval of "
        "the mean over seeds)"
    )
    return _save(fig, RunDir(run_dir).figure("fig3_returns.png"))


def _pair(cells: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """The paper's pair (④ and ⑦) when the run has them, else the first two cells."""
    by_tag = {c["tag"]: c for c in cells if c["tag"]}
    pair = paper_grid.PAIR
    return [by_tag[t] for t in pair] if set(pair) <= set(by_tag) else cells[:2]


def fig4_steps_loss(run_dir: Path) -> Path | None:
    """(a) manoeuvre steps per training episode, (b) critic loss per training step."""
    cells = _cells(run_dir)
    eps = _npz(RunDir(run_dir).episodes)
    steps = _npz(RunDir(run_dir).steps)
    if cells is None or eps is None or steps is None:
        return None
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8), layout="constrained")
    for i, c in enumerate(_pair(cells)):
        colour = _colour(c["meta"], i)
        _seed_curves(
            a, [eps["steps"][m, : eps["episodes"][m]] for m in c["models"]], colour, c["label"]
        )
        _seed_curves(b, [steps["critic_loss"][:, m] for m in c["models"]], colour, c["label"])
    a.set(title="(a) manoeuvre steps", xlabel="training episode", ylabel="steps per episode")
    b.set(title="(b) critic loss", xlabel="training step", ylabel="TD loss", yscale="log")
    for ax in (a, b):
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
    fig.suptitle("Fig. 4  Training curves (moving average; band: 95% interval over seeds)")
    return _save(fig, RunDir(run_dir).figure("fig4_steps_loss.png"))


# --------------------------------------------------------------------------- evaluation


def fig6_checkpoints(run_dir: Path) -> Path | None:
    """Average total return and success rate per checkpoint: one line per grid cell (mean
    over its seeds, band: the 95% bootstrap interval of that mean), the scripted controller
    dashed."""
    data = _eval(run_dir)
    if data is None:
        return None
    result = data[0]
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 3.8), layout="constrained")
    for i, c in enumerate(stats.cells_of(result.rows)):  # in model order
        colour = _colour(c.axes, i)
        for ax, vals, scale in ((a, c.ret, 1.0), (b, c.success, 100.0)):
            with warnings.catch_warnings():  # a checkpoint with no lane change: all NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(vals, axis=1)
            ax.plot(c.episodes, scale * mean, "o-", color=colour, ms=3, label=c.label)
            if len(c.seeds) > 1:
                lo, hi = stats.mean_band(vals.T)
                ax.fill_between(c.episodes, scale * lo, scale * hi, color=colour, alpha=0.2, lw=0)
    for r in result.rows:
        if r.model is None:
            a.axhline(number(r.avg_return), color="k", ls="--", lw=1, label="scripted")
            b.axhline(100 * number(r.success_rate), color="k", ls="--", lw=1)
    a.set(title="(a) average total return", xlabel="checkpoint (training episode)")
    _return_axis(a)
    b.set(
        title="(b) success rate", xlabel="checkpoint (training episode)", ylabel="%", ylim=(-3, 103)
    )
    for ax in (a, b):
        ax.grid(alpha=0.3)
    a.legend(fontsize=7)
    fig.suptitle(
        f"Fig. 6  {result.cases} cases per checkpoint, {result.performed} with a lane "
        "change (averages over those; band: 95% interval of the mean over seeds)"
    )
    return _save(fig, RunDir(run_dir).figure("fig6_checkpoints.png"))


def profiles(run_dir: Path) -> Path | None:
    """Performance profiles, one panel per k: for each cell the share of its models whose
    success rate at their last checkpoint is above each level, with its 95% interval."""
    path = RunDir(run_dir).eval_json
    if not path.is_file():
        return None
    cells = stats.cells_of(read(path, EvalResult).rows)
    if not cells:
        return None
    ks = sorted({c.axes["k"] for c in cells}, key=lambda k: (k is None, k))
    fig, axes = plt.subplots(
        1, len(ks), figsize=(3.8 * len(ks) + 0.6, 3.6), squeeze=False, layout="constrained"
    )
    for ax, k in zip(axes[0], ks, strict=True):
        for i, c in enumerate(cells):
            if c.axes["k"] != k:
                continue
            share, lo, hi = stats.performance_profile([c.final_success])
            colour = _colour(c.axes, i)
            ax.plot(100 * stats.TAUS, share, color=colour, lw=1.4, label=c.label)
            if np.isfinite(lo).all():
                ax.fill_between(100 * stats.TAUS, lo, hi, color=colour, alpha=0.2, lw=0)
        ax.set(
            title=f"k = {k}",
            xlabel="success rate τ (%)",
            ylabel="share of models above τ",
            ylim=(-0.03, 1.03),
        )
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7)
    n = stats.fewest_seeds(cells)
    fig.suptitle(
        f"Performance profiles at each model's last checkpoint ({n} seed{'s' * (n != 1)} per "
        "cell at least; band: 95% bootstrap interval)"
    )
    return _save(fig, RunDir(run_dir).figure("profiles.png"))


def fig_compare(table: list[stats.Difference], name_a: str, name_b: str, path: Path) -> Path:
    """``--compare``: B - A of the mean success rate per cell (rows of ``stats.compare``),
    (a) at the last checkpoint with its interval, (b) over checkpoints with bands."""
    labels = list(dict.fromkeys(r.label for r in table))
    last = max(r.episode for r in table)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 0.35 * len(labels) + 2.5), layout="constrained")
    for i, label in enumerate(labels):
        mine = sorted((r for r in table if r.label == label), key=lambda r: r.episode)
        d, lo, hi = (
            100 * np.asarray([number(getattr(r, k)) for r in mine])
            for k in ("diff", "diff_lo", "diff_hi")
        )
        ep = [r.episode for r in mine]
        colour = _colour(mine[0], i)
        j = ep.index(last)
        err = None if not np.isfinite(lo[j]) else [[d[j] - lo[j]], [hi[j] - d[j]]]
        a.errorbar(d[j], i, xerr=err, fmt="o", color=colour, capsize=3)
        b.plot(ep, d, "o-", color=colour, ms=3, label=label)
        if np.isfinite(lo).any():
            b.fill_between(ep, lo, hi, color=colour, alpha=0.2, lw=0)
    a.axvline(0, color="k", lw=0.8)
    a.set_yticks(range(len(labels)), labels)
    a.invert_yaxis()
    a.set(title=f"(a) checkpoint {last}", xlabel="B − A success rate (points)")
    b.axhline(0, color="k", lw=0.8)
    b.set(title="(b) over checkpoints", xlabel="checkpoint (training episode)", ylabel="points")
    b.legend(fontsize=7)
    for ax in (a, b):
        ax.grid(alpha=0.3)
    fig.suptitle(f"B = {name_b} against A = {name_a}: mean success rate (95% intervals)")
    return _save(fig, path)


TTC_SHOWN = 10.0  # s; longer (or no closing at all) is drawn at this value


def heldout_norms(run_dir: Path) -> Path | None:
    """Per cell (seeds pooled) and the scripted controller, the distribution over held-out
    lane changes of each norm's measure, the norm as a dashed red line
    (``jaxlc.evaluation.safety``)."""
    rd = RunDir(run_dir)
    cases = _npz(rd.heldout_cases)
    if cases is None or not rd.heldout_json.is_file():
        return None
    doc = read(rd.heldout_json, Heldout)
    dt = rd.load_config().env.dt
    perf = cases["performed"]
    measures = [
        {k: v[perf] for k, v in heldout.lane_change_measures(cases, row, dt).items()}
        for row in range(len(doc.rows))
    ]
    groups: dict[str, list[int]] = {}  # cell tag (or "scripted") -> policy rows
    for row, r in enumerate(doc.rows):
        tag = "scripted" if r.model is None else r.label.split(" ")[0]
        groups.setdefault(tag, []).append(row)
    fig, axes = plt.subplots(1, len(doc.norms), figsize=(3.2 * len(doc.norms), 3.6))
    for ax, norm in zip(axes, doc.norms, strict=True):
        name = norm.measure
        data = [np.concatenate([measures[i][name] for i in rows]) for rows in groups.values()]
        if name.startswith("min_"):
            data = [np.minimum(d, TTC_SHOWN) for d in data]
        data = [d[np.isfinite(d)] for d in data]
        ax.boxplot(data, whis=(1, 99), showfliers=True, flierprops={"markersize": 2})
        ax.axhline(norm.bound, color="red", ls="--", lw=1)
        ax.set_xticks(range(1, len(groups) + 1), list(groups), rotation=90, fontsize=7)
        ax.set_title(name.replace("_", " "), fontsize=9)
    fig.suptitle(
        f"{doc.lane_changes} held-out lane changes per model (whiskers 1-99%; successes "
        f"only for the R79 manoeuvre; TTC/THW drawn at most {TTC_SHOWN:g} s)",
        fontsize=9,
    )
    fig.tight_layout()
    return _save(fig, rd.figure("heldout_norms.png"))


def make_all(run_dir: Path) -> list[Path]:
    """Every figure whose data the run directory holds; returns the files written."""
    run_dir = Path(run_dir)
    makers = (
        fig3_returns,
        fig4_steps_loss,
        scenes.fig5_scenes,
        fig6_checkpoints,
        scenes.fig7_trajectories,
        scenes.speed_gaps,
        scenes.learning_gif,
        profiles,
        heldout_norms,
    )
    return [path for make in makers if (path := make(run_dir)) is not None]


def suite_figure(runs: Mapping[str, Sequence[dict]], path: Path) -> Path:
    """Success (%) by setting, each run's models side by side (a run per colour, a dot per
    model with its 95% interval; the scripted controller's rows left out; dotted: 99.9%)."""
    names = list(dict.fromkeys(r["setting"] for rows in runs.values() for r in rows))
    fig, ax = plt.subplots(figsize=(1.2 + 1.1 * len(names), 3.6))
    width = 0.8 / max(len(runs), 1)
    for i, (run, rows) in enumerate(runs.items()):
        mine = [r for r in rows if r["model"] is not None and r["lane_changes"]]
        at = [names.index(r["setting"]) for r in mine]
        # the setting's models spread across the run's share of the setting's width
        nth = [at[:j].count(s) for j, s in enumerate(at)]
        x = np.asarray(at, float) + (i + 0.5) * width - 0.4
        x += (np.asarray(nth) / np.maximum([at.count(s) - 1 for s in at], 1) - 0.5) * 0.6 * width
        y = 100 * np.asarray([r["success_rate"] for r in mine])
        lo = y - 100 * np.asarray([r["success_lo"] for r in mine])
        hi = 100 * np.asarray([r["success_hi"] for r in mine]) - y
        ax.errorbar(x, y, yerr=[lo, hi], fmt="o", ms=3, capsize=2, label=run)
    ax.axhline(99.9, color="0.5", lw=0.8, ls=":")  # the suite's bar (issue 79)
    ax.set_xticks(range(len(names)), names, rotation=30, ha="right")
    ax.set_ylabel("held-out success (%)")
    ax.legend(fontsize="small")
    return _save(fig, path)


def ams_curve(results: Sequence[ams.Estimate], path: Path) -> Path:
    """``ams_curve.png`` of ``python -m jaxlc.validate --method ams``: per policy, P(margin <=
    m) by AMS with its band, crude MC's on the initial particles as points with their bars."""
    fig, ax = plt.subplots(figsize=(6, 4))
    for r in results:
        cols = ("margin", "ams", "ams_lo", "ams_hi", "crude", "crude_lo", "crude_hi")
        got = (np.asarray([getattr(x, f) for x in r.curve]) for f in cols)
        m, p, p_lo, p_hi, c, c_lo, c_hi = got
        line = ax.step(m, p, where="post", label=f"{r.label} AMS")
        ax.fill_between(m, p_lo, p_hi, step="post", alpha=0.2, color=line[0].get_color())
        ax.errorbar(m, c, yerr=[c - c_lo, c_hi - c], fmt=".", color="k",
                    label="crude MC" if r is results[0] else None)  # fmt: skip
    ax.set_yscale("log")
    unit = "s" if results[0].kind == "timeout" else "m"
    ax.set_xlabel(f"margin to {results[0].kind.replace('_', ' ')}, {unit}")
    ax.set_ylabel("P(lane change with margin ≤ m) per case")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=120)
    plt.close(fig)
    return path
