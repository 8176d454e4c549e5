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
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import matplotlib

matplotlib.use("Agg")  # files only; no display on training machines

import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.animation import PillowWriter  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402
from matplotlib.ticker import FuncFormatter, SymmetricalLogLocator  # noqa: E402

from jaxlc.evaluation import heldout, stats  # noqa: E402
from jaxlc.evaluation.convergence import moving  # noqa: E402
from jaxlc.evaluation.numbers import number  # noqa: E402
from jaxlc.evaluation.results import OUTCOMES, rank_models  # noqa: E402
from jaxlc.paper import grid as paper_grid  # noqa: E402
from jaxlc.sim.render import road_to_world  # noqa: E402
from jaxlc.sim.road import origin_lane, reference_y  # noqa: E402
from jaxlc.study.rundir import RunDir  # noqa: E402

SCENE_BEHIND, SCENE_AHEAD = 90.0, 30.0  # m of road shown behind and ahead of the ego
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


_npz = RunDir.load_npz


def _eval(run_dir: Path) -> tuple[dict[str, Any], dict, dict] | None:
    path = RunDir(run_dir).eval_json
    traces, cases = _npz(RunDir(run_dir).traces), _npz(RunDir(run_dir).cases)
    if not path.is_file() or traces is None or cases is None:
        return None
    return json.loads(path.read_text()), traces, cases


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


def _save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


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
    for i, c in enumerate(stats.cells_of(result["rows"])):  # in model order
        colour = _colour(c.axes, i)
        for ax, vals, scale in ((a, c.ret, 1.0), (b, c.success, 100.0)):
            with warnings.catch_warnings():  # a checkpoint with no lane change: all NaN
                warnings.simplefilter("ignore", RuntimeWarning)
                mean = np.nanmean(vals, axis=1)
            ax.plot(c.episodes, scale * mean, "o-", color=colour, ms=3, label=c.label)
            if len(c.seeds) > 1:
                lo, hi = stats.mean_band(vals.T)
                ax.fill_between(c.episodes, scale * lo, scale * hi, color=colour, alpha=0.2, lw=0)
    for r in result["rows"]:
        if r["model"] is None:
            a.axhline(number(r["avg_return"]), color="k", ls="--", lw=1, label="scripted")
            b.axhline(100 * number(r["success_rate"]), color="k", ls="--", lw=1)
    a.set(title="(a) average total return", xlabel="checkpoint (training episode)")
    _return_axis(a)
    b.set(
        title="(b) success rate", xlabel="checkpoint (training episode)", ylabel="%", ylim=(-3, 103)
    )
    for ax in (a, b):
        ax.grid(alpha=0.3)
    a.legend(fontsize=7)
    fig.suptitle(
        f"Fig. 6  {result['cases']} cases per checkpoint, {result['performed']} with a lane "
        "change (averages over those; band: 95% interval of the mean over seeds)"
    )
    return _save(fig, RunDir(run_dir).figure("fig6_checkpoints.png"))


def profiles(run_dir: Path) -> Path | None:
    """Performance profiles, one panel per k: for each cell the share of its models whose
    success rate at their last checkpoint is above each level, with its 95% interval."""
    path = RunDir(run_dir).eval_json
    if not path.is_file():
        return None
    cells = stats.cells_of(json.loads(path.read_text())["rows"])
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


def fig_compare(table: list[dict[str, Any]], name_a: str, name_b: str, path: Path) -> Path:
    """``--compare``: B - A of the mean success rate per cell (rows of ``stats.compare``),
    (a) at the last checkpoint with its interval, (b) over checkpoints with bands."""
    labels = list(dict.fromkeys(r["label"] for r in table))
    last = max(r["episode"] for r in table)
    fig, (a, b) = plt.subplots(1, 2, figsize=(11, 0.35 * len(labels) + 2.5), layout="constrained")
    for i, label in enumerate(labels):
        mine = sorted((r for r in table if r["label"] == label), key=lambda r: r["episode"])
        d, lo, hi = (
            100 * np.asarray([number(r[k]) for r in mine]) for k in ("diff", "diff_lo", "diff_hi")
        )
        ep = [r["episode"] for r in mine]
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


def _best(result: dict[str, Any]) -> tuple[int, list[int]] | None:
    """Best model and its evaluated policy rows (eval.json order), by episode."""
    ranked = rank_models(result["rows"])
    if not ranked:
        return None
    m = ranked[0]["model"]
    rows = [i for i, r in enumerate(result["rows"]) if r["model"] == m]
    return m, sorted(rows, key=lambda i: result["rows"][i]["episode"])


def _best_traces(run_dir: Path) -> tuple[dict, dict, dict, Any, list[int]] | None:
    """``(result, traces, cases, env config, best model's policy rows by episode)`` of an
    evaluated run; None when it has no evaluation or no model was ranked."""
    data = _eval(run_dir)
    best = None if data is None else _best(data[0])
    if best is None:
        return None
    return *data, RunDir(run_dir).load_config().env, best[1]


def _curvature(tr: dict[str, np.ndarray], pi: int, j: int) -> float:
    """The traced case's road curvature (0 where the trace holds none: a straight road)."""
    return float(tr["curvature"][pi, j]) if "curvature" in tr else 0.0


def _world(s: Any, y: Any, kappa: float, s0: float, p: Any) -> tuple[np.ndarray, np.ndarray]:
    """Road-frame points (s along the road's centre line, y across; ``jaxlc.sim.kinematics``)
    drawn on the bent road: X along the road's tangent at ``s0`` (offset by ``s0``, so the axis
    still reads as road position), Y across it (= y at ``s0``). The identity when straight."""
    s, y = np.asarray(s, float), np.asarray(y, float)
    if kappa == 0.0:
        return s, y
    y_ref = reference_y(p)
    x_w, y_w = road_to_world(s - s0, y - y_ref, kappa)
    return s0 + x_w, y_ref + y_w


def _along(kappa: float) -> str:
    """Fig. 7's x-axis: distance along a straight road, along the start's tangent on a bend."""
    if kappa == 0.0:
        return "distance since the manoeuvre began (m)"
    return f"along the road's tangent where the manoeuvre began (m); curvature {kappa:g} 1/m"


def _lanes(ax: Any, p: Any, x0: float, x1: float, kappa: float = 0.0, s0: float = 0.0) -> None:
    w, n = p.lane_width, p.lanes
    s = np.linspace(x0, x1, 2 if kappa == 0.0 else 200)
    for j in range(n + 1):
        edge = j in (0, n)
        ax.plot(
            *_world(s, np.full_like(s, j * w), kappa, s0, p),
            color="k" if edge else "0.5",
            lw=1.2 if edge else 0.8,
            ls="-" if edge else (0, (6, 6)),
        )


def fig7_trajectories(run_dir: Path) -> Path | None:
    """(a) the final checkpoint's left and right lane changes, (b) one case over checkpoints."""
    found = _best_traces(run_dir)
    if found is None:
        return None
    result, tr, _, p, prows = found
    final = prows[-1]
    fig, (a, b) = plt.subplots(2, 1, figsize=(9, 6.5), layout="constrained")
    # The cases share one road when the config's curvature is a number: draw it bent then.
    kappas = {_curvature(tr, pi, j) for pi in (0, final) for j in range(len(tr["traced"]))}
    kappa = kappas.pop() if len(kappas) == 1 else 0.0
    span = 1.0
    for j, case in enumerate(tr["traced"]):
        for pi, style in ((0, dict(color="0.4", ls="--", lw=1)), (final, {})):
            n = int(tr["frames"][pi, j])
            if n < 2:
                continue
            x, y = _world(tr["x"][pi, j, :n] - tr["x"][pi, j, 0], tr["y"][pi, j, :n], kappa, 0, p)
            span = max(span, tr["x"][pi, j, n - 1] - tr["x"][pi, j, 0])
            colour = "tab:red" if tr["side"][j] > 0 else "tab:blue"
            kw = {"color": colour, "lw": 1.6, **style}
            lab = None
            if pi == final:
                lab = f"case {case} ({'left' if tr['side'][j] > 0 else 'right'})"
            elif j == 0:
                lab = "scripted controller"
            a.plot(x, y, label=lab, **kw)
    _lanes(a, p, 0, span, kappa)
    label = result["rows"][final]["label"]
    a.set(
        title=f"(a) {label}, checkpoint {result['rows'][final]['episode']}",
        xlabel=_along(kappa),
        ylabel="y (m)",
    )
    a.legend(fontsize=7, loc="center right", ncols=2)

    j = int(np.argmax(tr["side"] > 0)) if (tr["side"] > 0).any() else 0
    cmap = plt.get_cmap("viridis")
    span = 1.0
    kappa = _curvature(tr, final, j)  # one case: one road
    for n_i, pi in enumerate(prows):
        n = int(tr["frames"][pi, j])
        if n < 2:
            continue
        x, y = _world(tr["x"][pi, j, :n] - tr["x"][pi, j, 0], tr["y"][pi, j, :n], kappa, 0, p)
        span = max(span, tr["x"][pi, j, n - 1] - tr["x"][pi, j, 0])
        last = pi == final
        b.plot(
            x,
            y,
            color="tab:red" if last else cmap(n_i / max(1, len(prows) - 1)),
            lw=2.2 if last else 1.1,
            label=f"episode {result['rows'][pi]['episode']}",
        )
    _lanes(b, p, 0, span, kappa)
    b.set(
        title=f"(b) case {tr['traced'][j]} as training goes on",
        xlabel=_along(kappa),
        ylabel="y (m)",
    )
    b.legend(fontsize=7, ncols=4, loc="center right")
    fig.suptitle("Fig. 7  Lane-change trajectories")
    return _save(fig, RunDir(run_dir).figure("fig7_trajectories.png"))


def speed_gaps(run_dir: Path) -> Path | None:
    """The longitudinal side of the drawn lane changes: the ego's speed and its net gaps to
    the target lane's lead and lag (along the road's centre line) over the manoeuvre, the best
    model's final checkpoint (solid) beside the scripted controller (dashed), whose
    longitudinal motion is the IDM's."""
    found = _best_traces(run_dir)
    if found is None or "v" not in found[1]:  # a trace without the speed
        return None
    result, tr, _, p, prows = found
    final = prows[-1]
    fig, axes = plt.subplots(1, 3, figsize=(12, 3.6), layout="constrained")
    for j, case in enumerate(tr["traced"]):
        colour = f"C{j}"
        for pi, ls in ((0, "--"), (final, "-")):
            n = int(tr["frames"][pi, j])
            if n < 2:
                continue
            t = np.arange(n) * p.dt
            x = tr["x"][pi, j, :n]
            lead = np.where(tr["has_lead"][pi, j, :n], tr["lead_x"][pi, j, :n] - x, np.nan)
            lag = np.where(tr["has_lag"][pi, j, :n], x - tr["lag_x"][pi, j, :n], np.nan)
            lab = f"case {case}" if pi == final else None
            kw = {"color": colour, "ls": ls, "lw": 1.5}
            axes[0].plot(t, tr["v"][pi, j, :n], label=lab, **kw)
            axes[1].plot(t, lead - p.vehicle_length, **kw)
            axes[2].plot(t, lag - p.vehicle_length, **kw)
    for ax, what in zip(
        axes, ("ego speed (m/s)", "gap to target lead (m)", "gap to target lag (m)"), strict=True
    ):
        ax.set(xlabel="time since the manoeuvre began (s)", ylabel=what)
    axes[0].legend(fontsize=7)
    row = result["rows"][final]
    fig.suptitle(
        f"Speed and gaps: {row['label']}, checkpoint {row['episode']} (solid); "
        "scripted controller, IDM speed (dashed)"
    )
    return _save(fig, RunDir(run_dir).figure("speed_gaps.png"))


def draw_scene(ax: Any, tr: dict[str, np.ndarray], pi: int, j: int, f: int, p: Any) -> None:
    """One frame: ego red (with its dotted past path), the gap's lead and lag green, others
    blue, lane markings; the view follows the ego, and a curved road is drawn bent around it
    (``_world``; every body turned by the road's direction where it is)."""
    L, W, lw = p.vehicle_length, p.vehicle_width, p.lane_width
    ex, ey, psi = tr["x"][pi, j, f], tr["y"][pi, j, f], tr["psi"][pi, j, f]
    kappa = _curvature(tr, pi, j)
    x0, x1 = ex - SCENE_BEHIND, ex + SCENE_AHEAD
    _lanes(ax, p, x0, x1, kappa, ex)

    def body(s: float, y: float, heading: float, colour: str) -> None:  # centre (s, y)
        cx, cy = _world(s, y, kappa, ex, p)
        ax.add_patch(
            Rectangle(
                (cx - L / 2, cy - W / 2),
                L,
                W,
                angle=np.degrees(heading + kappa * (s - ex)),
                rotation_point="center",
                color=colour,
            )
        )

    target = origin_lane(p) + int(tr["side"][j])
    xs, act = tr["traffic_x"][pi, j, f], tr["traffic_active"][pi, j, f]
    centre = (np.arange(p.lanes)[:, None] + 0.5) * lw + np.zeros_like(xs)  # rows are lanes
    ys = tr["traffic_y"][pi, j, f] if "traffic_y" in tr else centre  # between two, changing
    for lane in range(p.lanes):
        for x, y in zip(xs[lane][act[lane]], ys[lane][act[lane]], strict=True):
            if not x0 - L < x < x1 + L:
                continue
            gap_car = abs(y - (target + 0.5) * lw) < lw and any(
                tr[h][pi, j, f] and np.isclose(x, tr[k][pi, j, f])
                for h, k in (("has_lead", "lead_x"), ("has_lag", "lag_x"))
            )
            body(x - L / 2, y, 0.0, "tab:green" if gap_car else "tab:blue")
    past = _world(tr["x"][pi, j, : f + 1] - L / 2, tr["y"][pi, j, : f + 1], kappa, ex, p)
    ax.plot(*past, "r:", lw=1.2)
    body(ex - L / 2 * np.cos(psi), ey - L / 2 * np.sin(psi), psi, "tab:red")
    ax.set_xlim(x0, x1)
    edges = [
        _world(np.array([x0, ex, x1]), np.full(3, y), kappa, ex, p)[1] for y in (0, lw * p.lanes)
    ]
    ax.set_ylim(min(e.min() for e in edges) - 0.5, max(e.max() for e in edges) + 0.5)
    ax.set_aspect("equal")
    ax.set_yticks([])


def _checkpoint_picks(prows: list[int], n: int) -> list[int]:
    idx = np.unique(np.linspace(0, len(prows) - 1, min(n, len(prows))).round().astype(int))
    return [prows[i] for i in idx]


def fig5_scenes(run_dir: Path, panels: int = 6) -> Path | None:
    """Scene at the end of one case's manoeuvre for up to ``panels`` checkpoints."""
    found = _best_traces(run_dir)
    if found is None:
        return None
    result, tr, cases, p, prows = found
    picks = _checkpoint_picks(prows, panels)
    j = 0
    fig, axes = plt.subplots(
        len(picks), 1, figsize=(10, 1.5 * len(picks) + 0.6), squeeze=False, layout="constrained"
    )
    for ax, pi in zip(axes[:, 0], picks, strict=True):
        f = max(0, int(tr["frames"][pi, j]) - 1)
        draw_scene(ax, tr, pi, j, f, p)
        reason = OUTCOMES[int(cases["reason"][pi, tr["traced"][j]])]
        ax.set_title(
            f"checkpoint {result['rows'][pi]['episode']}: {reason.replace('_', ' ')} "
            f"after {f * p.dt:.1f} s",
            fontsize=9,
            loc="left",
        )
    axes[-1, 0].set_xlabel("x (m)")
    fig.suptitle(
        f"Fig. 5  Case {tr['traced'][j]} at chosen checkpoints of "
        f"{result['rows'][prows[-1]]['label']} (red: ego, green: gap, blue: others)"
    )
    return _save(fig, RunDir(run_dir).figure("fig5_scenes.png"))


def learning_gif(run_dir: Path, checkpoints: int = 6, every: int = 3) -> Path | None:
    """Animated lane changes (one left, one right case) of the best model, checkpoint after
    checkpoint; every ``every``-th simulation step is a frame."""
    found = _best_traces(run_dir)
    if found is None:
        return None
    result, tr, cases, p, prows = found
    picks = _checkpoint_picks(prows, checkpoints)
    left = np.nonzero(tr["side"] > 0)[0]
    right = np.nonzero(tr["side"] < 0)[0]
    shown = [int(g[0]) for g in (left, right) if len(g)] or [0]
    frames = []
    for pi in picks:
        n = max(int(tr["frames"][pi, j]) for j in shown)
        frames += [(pi, f) for f in range(0, n, every)] + [(pi, n - 1)] * 5  # pause at the end
    # Fixed layout, no axes, one draw per frame: a GIF of ~200 frames stays a few seconds.
    fig, axes = plt.subplots(len(shown), 1, figsize=(8, 1.0 * len(shown) + 0.5), squeeze=False)
    fig.subplots_adjust(left=0.01, right=0.99, top=0.86, bottom=0.02, hspace=0.35)

    def draw(pi: int, f: int) -> None:
        for ax, j in zip(axes[:, 0], shown, strict=True):
            ax.clear()
            fj = min(f, int(tr["frames"][pi, j]) - 1)
            draw_scene(ax, tr, pi, j, max(fj, 0), p)
            ax.set_axis_off()
            end = fj == int(tr["frames"][pi, j]) - 1  # the outcome once it is reached
            reason = OUTCOMES[int(cases["reason"][pi, tr["traced"][j]])] if end else "…"
            ax.set_title(
                f"case {tr['traced'][j]}  t = {fj * p.dt:4.1f} s  {reason.replace('_', ' ')}",
                fontsize=8,
                loc="left",
            )
        fig.suptitle(
            f"{result['rows'][pi]['label']}, checkpoint {result['rows'][pi]['episode']}",
            fontsize=10,
        )

    path = RunDir(run_dir).figure("learning.gif")
    path.parent.mkdir(parents=True, exist_ok=True)
    writer = PillowWriter(fps=10)
    with writer.saving(fig, path, dpi=90):
        for pi, f in frames:
            draw(pi, f)
            writer.grab_frame()
    plt.close(fig)
    return path


TTC_SHOWN = 10.0  # s; longer (or no closing at all) is drawn at this value


def heldout_norms(run_dir: Path) -> Path | None:
    """Per cell (seeds pooled) and the scripted controller, the distribution over held-out
    lane changes of each norm's measure, the norm as a dashed red line
    (``jaxlc.evaluation.safety``)."""
    rd = RunDir(run_dir)
    cases = _npz(rd.heldout_cases)
    if cases is None or not rd.heldout_json.is_file():
        return None
    doc = json.loads(rd.heldout_json.read_text())
    dt = rd.load_config().env.dt
    perf = cases["performed"]
    measures = [
        {k: v[perf] for k, v in heldout.lane_change_measures(cases, row, dt).items()}
        for row in range(len(doc["rows"]))
    ]
    groups: dict[str, list[int]] = {}  # cell tag (or "scripted") -> policy rows
    for row, r in enumerate(doc["rows"]):
        tag = "scripted" if r["model"] is None else r["label"].split(" ")[0]
        groups.setdefault(tag, []).append(row)
    fig, axes = plt.subplots(1, len(doc["norms"]), figsize=(3.2 * len(doc["norms"]), 3.6))
    for ax, norm in zip(axes, doc["norms"], strict=True):
        name = norm["measure"]
        data = [np.concatenate([measures[i][name] for i in rows]) for rows in groups.values()]
        if name.startswith("min_"):
            data = [np.minimum(d, TTC_SHOWN) for d in data]
        data = [d[np.isfinite(d)] for d in data]
        ax.boxplot(data, whis=(1, 99), showfliers=True, flierprops={"markersize": 2})
        ax.axhline(norm["bound"], color="red", ls="--", lw=1)
        ax.set_xticks(range(1, len(groups) + 1), list(groups), rotation=90, fontsize=7)
        ax.set_title(name.replace("_", " "), fontsize=9)
    fig.suptitle(
        f"{doc['lane_changes']} held-out lane changes per model (whiskers 1-99%; successes "
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
        fig5_scenes,
        fig6_checkpoints,
        fig7_trajectories,
        speed_gaps,
        learning_gif,
        profiles,
        heldout_norms,
    )
    return [path for make in makers if (path := make(run_dir)) is not None]
