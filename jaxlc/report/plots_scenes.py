"""The figures of single lane changes from a run's evaluation (``eval/traces.npz``): Fig. 5
scenes at chosen checkpoints, Fig. 7 trajectories, the speeds and gaps of the drawn cases,
``learning.gif`` (lane changes across checkpoints), ``draw_scene`` (one frame), and a validated
failure replayed (``validation_scenes``, ``replay_case``), AMS's nearest misses (``ams_misses``,
``replay_miss``); drawn on the road's bend where the case had one. Also what every figure
module shares: matplotlib on its file backend (Agg: files only, no display on training
machines), a run's evaluation files, a figure saved. The rest of the figures:
``jaxlc.report.plots``."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import jax
import matplotlib
import numpy as np

matplotlib.use("Agg")  # before pyplot is imported anywhere

import matplotlib.pyplot as plt  # noqa: E402
from matplotlib.animation import PillowWriter  # noqa: E402
from matplotlib.patches import Rectangle  # noqa: E402

from jaxlc import config  # noqa: E402
from jaxlc.evaluation import ams, validation, validation_io  # noqa: E402
from jaxlc.evaluation.numbers import read  # noqa: E402
from jaxlc.evaluation.results import OUTCOMES, EvalError, EvalResult, rank_models  # noqa: E402
from jaxlc.sim.env import CRUISE, GAP, RL, WAIT, EnvParams  # noqa: E402
from jaxlc.sim.render import render_frame, road_to_world  # noqa: E402
from jaxlc.sim.road import origin_lane, reference_y  # noqa: E402
from jaxlc.study.rundir import RunDir  # noqa: E402

SCENE_BEHIND, SCENE_AHEAD = 90.0, 30.0  # m of road shown behind and ahead of the ego
npz = RunDir.load_npz


def eval_files(run_dir: Path) -> tuple[EvalResult, dict, dict] | None:
    """``(eval.json, traces.npz, cases.npz)`` of an evaluated run; None when one is missing."""
    path = RunDir(run_dir).eval_json
    traces, cases = npz(RunDir(run_dir).traces), npz(RunDir(run_dir).cases)
    if not path.is_file() or traces is None or cases is None:
        return None
    return read(path, EvalResult), traces, cases


def save(fig: Any, path: Path) -> Path:
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110, bbox_inches="tight")
    plt.close(fig)
    return path


def _best(result: EvalResult) -> tuple[int, list[int]] | None:
    """Best model and its evaluated policy rows (eval.json order), by episode."""
    ranked = rank_models(result.rows)
    if not ranked:
        return None
    m = ranked[0].model
    rows = [i for i, r in enumerate(result.rows) if r.model == m]
    return m, sorted(rows, key=lambda i: result.rows[i].episode)


def _best_traces(run_dir: Path) -> tuple[EvalResult, dict, dict, Any, list[int]] | None:
    """``(result, traces, cases, env config, best model's policy rows by episode)`` of an
    evaluated run; None when it has no evaluation or no model was ranked."""
    data = eval_files(run_dir)
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
    label = result.rows[final].label
    a.set(
        title=f"(a) {label}, checkpoint {result.rows[final].episode}",
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
            label=f"episode {result.rows[pi].episode}",
        )
    _lanes(b, p, 0, span, kappa)
    b.set(
        title=f"(b) case {tr['traced'][j]} as training goes on",
        xlabel=_along(kappa),
        ylabel="y (m)",
    )
    b.legend(fontsize=7, ncols=4, loc="center right")
    fig.suptitle("Fig. 7  Lane-change trajectories")
    return save(fig, RunDir(run_dir).figure("fig7_trajectories.png"))


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
    row = result.rows[final]
    fig.suptitle(
        f"Speed and gaps: {row.label}, checkpoint {row.episode} (solid); "
        "scripted controller, IDM speed (dashed)"
    )
    return save(fig, RunDir(run_dir).figure("speed_gaps.png"))


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
            f"checkpoint {result.rows[pi].episode}: {reason.replace('_', ' ')} "
            f"after {f * p.dt:.1f} s",
            fontsize=9,
            loc="left",
        )
    axes[-1, 0].set_xlabel("x (m)")
    fig.suptitle(
        f"Fig. 5  Case {tr['traced'][j]} at chosen checkpoints of "
        f"{result.rows[prows[-1]].label} (red: ego, green: gap, blue: others)"
    )
    return save(fig, RunDir(run_dir).figure("fig5_scenes.png"))


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
            f"{result.rows[pi].label}, checkpoint {result.rows[pi].episode}",
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


# --------------------------------------------------------------------------- validation


def validation_scenes(run_dir: Path, out: Path, cfg: config.Config) -> Path | None:
    """``scenes.png`` of ``jaxlc.validate``'s ``out``: per failure kind, its highest-weight
    saved case replayed, the scene at its last step (the ego red, the gap's lead and lag
    green)."""
    cases = validation_io.read_cases(out)
    kinds = [k for k in validation.KINDS if any(k in c.kinds for c in cases)]
    if not kinds:
        return None
    doc, p = validation_io.Validation.read(out / "validate.json"), EnvParams.from_config(cfg.env)
    fig, axes = plt.subplots(len(kinds), 1, figsize=(8, 1.3 * len(kinds) + 0.3), squeeze=False)
    for ax, kind in zip(axes[:, 0], kinds, strict=True):
        case = next(c for c in cases if kind in c.kinds)  # highest weight first
        tr, _ = validation_io.rerun(run_dir, cfg, doc, case)
        n = sum(kind in c.kinds for c in cases)
        title = f"{kind} ({n} saved): {case.label}, case {case.index}, {case.reason}, "
        _draw_case(ax, tr, max(int(tr["frames"][0, 0]) - 1, 0), p, title + _log10_w(case))
    return save(fig, out / "scenes.png")


def _log10_w(case: validation.Case) -> str:
    return f"log10 w = {case.log_w / math.log(10):.2f}"


def _draw_case(ax: Any, tr: dict, frame: int, p: EnvParams, title: str) -> None:
    """A saved case's scene at ``frame`` (the ego red, the gap's lead and lag green)."""
    draw_scene(ax, tr, 0, 0, frame, p)
    ax.set_axis_off()
    ax.set_title(title, fontsize=8, loc="left")


def replay_case(run_dir: Path, index: int, out: Path | None = None) -> tuple[Path, bool]:
    """Run ``validate/cases.json``'s case ``index`` again and draw it as
    ``validate/case_INDEX.gif``; returns the path and whether the outcome and weight are the
    saved ones bit for bit (``validation_io.replay``)."""
    cfg, case, tr, same = validation_io.replay(run_dir, index, out)
    path = validation_io.validate_dir(run_dir, out) / f"case_{index}.gif"
    p = EnvParams.from_config(cfg.env)
    fig, ax = plt.subplots(figsize=(8, 1.5))
    writer = PillowWriter(fps=10)
    with writer.saving(fig, path, dpi=90):
        for f in range(max(int(tr["frames"][0, 0]), 1)):
            ax.clear()
            title = f"{case.label}  t = {f * p.dt:4.1f} s  {case.reason}  "
            _draw_case(ax, tr, f, p, title + _log10_w(case))
            writer.grab_frame()
    plt.close(fig)
    return path, same


# --------------------------------------------------------------------------- AMS

PHASES = {WAIT: "waiting", CRUISE: "cruise", GAP: "gap search", RL: "lane change"}


def _draw_miss(ax: Any, est: ams.Estimate, miss: ams.Miss, states: Any, f: int, p: EnvParams,
               extra: str = "", fontsize: int = 8) -> None:  # fmt: skip
    """A replayed miss's scene after step ``f`` (``render_frame``), titled with its margin,
    time and phase (and ``extra``)."""
    ax.imshow(render_frame(jax.tree.map(lambda x: x[f], states), p))
    ax.set_axis_off()
    unit = "s" if est.kind == "timeout" else "m"
    title = (f"{est.label}, run {miss.repeat}: {est.kind} margin {miss.margin:.3f} {unit}; "
             f"t = {(f + 1) * p.dt:.1f} s, {PHASES[int(states.ego.phase[f])]}")  # fmt: skip
    ax.set_title(title + extra, fontsize=fontsize, loc="left")


def ams_misses(run_dir: Path, out: Path | None = None) -> Path | None:
    """``ams_misses.png``: each of ``ams.json``'s nearest misses replayed, its scene at its
    closest moment (the first step its score path reached its top: the ego red)."""
    out = validation_io.validate_dir(run_dir, out)
    misses = validation_io.misses(out)
    if not misses:
        return None
    fig, axes = plt.subplots(len(misses), 1, figsize=(8, 1.2 * len(misses) + 0.2), squeeze=False)
    for ax, (est, miss) in zip(axes[:, 0], misses, strict=True):
        _, path, states, p = validation_io.rerun_miss(run_dir, est, miss, exact=False)
        _draw_miss(ax, est, miss, states, int(np.argmax(path)), p)
    return save(fig, out / "ams_misses.png")


def replay_miss(run_dir: Path, index: int, out: Path | None = None) -> tuple[Path, bool]:
    """``ams.json``'s nearest miss ``index`` (``validation_io.misses``' order) run again from
    its key chain and drawn as ``validate/ams_miss_INDEX.gif`` from 3 s before its gap search
    on (at most 300 frames, in real time); returns the path and whether its margin is the
    saved one bit for bit."""
    out = validation_io.validate_dir(run_dir, out)
    misses = validation_io.misses(out)
    if not 0 <= index < len(misses):
        raise EvalError(f"--replay {index}: ams.json holds {len(misses)} nearest misses")
    est, miss = misses[index]
    margin, path, states, p = validation_io.rerun_miss(run_dir, est, miss, exact=True)
    phase = np.asarray(states.ego.phase)
    start = max(int(np.argmax(phase >= GAP)) - int(round(3.0 / p.dt)), 0)
    stride = max(1, -(-(len(phase) - start) // 300))
    fig, ax = plt.subplots(figsize=(8, 1.3))
    writer, gif = PillowWriter(fps=1.0 / (p.dt * stride)), out / f"ams_miss_{index}.gif"
    with writer.saving(fig, gif, dpi=90):
        for f in range(start, len(phase), stride):
            ax.clear()
            so_far = f"so far {-path[f]:.2f}" if path[f] > -est.cap else "not yet"
            _draw_miss(ax, est, miss, states, f, p, f"; margin {so_far}", fontsize=7)
            writer.grab_frame()
    plt.close(fig)
    return gif, margin == miss.margin
