"""The prose of ``report.md`` and ``compare.md``: each paragraph and claim row a template whose
``{fields}`` ``jaxlc.report.report`` fills with the run's numbers (``str.format``); and the
terminal's plain-text tables of the evaluation's rows (``format_table``, ``format_heldout``)."""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from jaxlc.evaluation.numbers import DASH, defined
from jaxlc.evaluation.results import OUTCOMES, HeldoutRow, Row

TERMINAL_DASH = "-"  # an undefined number in a plain-text table for the terminal (ASCII)


def percent(v: Any, digits: int = 1, unit: str = "%", missing: str = DASH) -> str:
    """A share ``v`` in [0, 1] as a percentage with ``digits`` decimals and ``unit``."""
    return f"{100 * v:.{digits}f}{unit}" if defined(v) else missing


def interval(est: Any, lo: Any, hi: Any, fmt: str, scale: float = 1.0) -> str:
    """``"est [lo, hi]"`` each times ``scale`` by ``fmt``; the estimate alone without bounds."""
    if not defined(est):
        return DASH
    text = format(scale * est, fmt)
    if defined(lo):
        text += f" [{format(scale * lo, fmt)}, {format(scale * hi, fmt)}]"
    return text


# Figure file -> its caption in the report's list of figures (those a run has).
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

INTRO = (
    "{cases} lane-change cases (seed {seed}, step cap {max_steps}), the same for every "
    "checkpoint, no exploration noise. {performed} cases reached the RL phase ({left} left, "
    "{right} right lane changes); of the others, {no_gap} found no acceptable gap, {collision} "
    "collided before the lane change and {unfinished} hit the step cap (the same for every "
    "policy: the action only acts in the RL phase). Success rate and average return are over "
    "the cases with a lane change; duration, peak lateral acceleration (|v·ω|), peak yaw rate "
    "and overshoot past the target centre line are means over the successful ones. Outcome "
    "counts add up to the cases. Config hash `{config_hash}`."
)

# --- the best model ---------------------------------------------------------------------------
NO_MODEL = "No model checkpoint was evaluated."
BEST = (
    "**Best model: {label} (model {model}, seed {seed})**, at checkpoint {episode}: success "
    "rate {rate} of {performed} lane changes, average return {ret}."
)
RUNNER_UP = (
    "Runner-up: {label} (model {model}, seed {seed}): success rate {rate}, average return "
    "{ret}. Margin: success rate {d_rate}, average return {d_ret}."
)
TIE = "The success rates tie, so the return decides; treat the ranking as weak."
TIMEOUTS = (
    "Its {n} timeout{ends} at a median |Δd| of {offset} m from the target centre line, |ψ| "
    "{heading} rad and |ω| {yaw_rate} rad/s{box}: a large |Δd| with a small |ω| is stopping "
    "short, a large |ω| oscillating, all three near the box a tight success box."
)
SUCCESS_BOX = (
    " (success box: |Δd| ≤ {offset_m:g} m, |ψ| ≤ {heading:g} rad, |ω| ≤ {yaw_rate:g} rad/s)"
)

# --- success over seeds, and one run against another ------------------------------------------
SEEDS = (
    "{cells} grid cells, {n} seed{s} in the smallest; each model at its last evaluated "
    "checkpoint. Brackets: 95% bootstrap intervals over seeds (resampled within each cell; "
    "`jaxlc.evaluation.stats`)."
)
SEEDS_NOTE = "**Note: {note}** (train with `--seeds N`)."
IMPROVEMENT = (
    "Probability of improvement P(row > column) of the final success rate over pairs of seeds "
    "(ties count half):"
)
COMPARE = (
    "Mean evaluated success rate over seeds per grid cell at checkpoint {last}; B − A with a "
    "95% bootstrap interval (each run's seeds resampled on their own). A: `{run_a}`, B: "
    "`{run_b}`. Every checkpoint: `compare.csv`."
)
COMPARE_NOTE = "Note: {note} in each run."

# --- the paper's other figures: one claim a row (| claim | paper | this run | agrees |) -------
CLAIM_BEST = "| best model | {paper} | {ours} | {agrees} |"
CLAIM_SUCCESS = (
    "| success rate at the final checkpoint, over cases with a lane change ({who}) | 100% | "
    "{success} ({n_success} of {performed}; {out_of_bounds} out of bounds, {collision} "
    "collisions, {timeout} timeouts) | {agrees} |"
)
CLAIM_PERFORMED = (
    "| cases that performed a lane change (agrees: within ±10 points) | 80 of 100 | "
    "{performed} of {cases} ({share:.0f}%) | {agrees} |"
)
CLAIM_RETURN = (
    "| average return rises over checkpoints, then plateaus (Fig. 6) | from −20 (a default for "
    "no lane change) | {first} at checkpoint {first_episode} → {last} at {last_episode} (raw "
    "returns; eq. (11) cannot give −20) | {rises} |"
)
CLAIM_DURATION = (
    "| lane-change duration like a human's | humans 3–8 s (mean ≈ 6 s) | {ours} (best model, "
    "successful cases{scripted}) | {agrees} |"
)

# --- held-out lane changes --------------------------------------------------------------------
HELDOUT_HAZARDS = (
    " Cut-ins met and braking events of the vehicles around the ego are counted per lane change "
    "(`cut_ins`, `met_cut_in`, `brakes_near`, `met_braking` in `heldout.csv`); each collision "
    "names what the vehicle hit was doing."
)
HELDOUT = (
    "Each model's final checkpoint and the scripted controller on {lane_changes} held-out lane "
    "changes ({cases} cases of `{key_stream}`, a key stream apart from the protocol's cases and "
    "from training), no noise. Per model: two-sided 95% Clopper-Pearson intervals, and "
    "`failure <`, the one-sided 95% upper bound on the failure rate. The norms, per lane "
    "change: {norms}. A lane change is inside every norm when it succeeds and meets all of "
    "them; TTC and time headway are the minimum over the manoeuvre of those to the target "
    "lane's lead and lag and the own lane's leader, counted {counted} "
    "(`jaxlc.evaluation.safety`); the table gives their 5th percentile over the lane changes, "
    "∞ where fewer than 5% close in. Figure: [heldout_norms.png](figures/heldout_norms.png)."
)
# How headway and TTC were counted where heldout.json names no ``conflicts_counted``.
EVERY_STEP = "on every step from the manoeuvre's start"
CLAIM_D = "**Claim (d)**: {figures}: **{verdict}** (supported when the bound is at most 1%)."
CLAIM_D_MISSING = "needs the held-out lane changes (evaluate with --lane-changes above 0)"
NO_COLLISIONS = "No held-out lane change of any policy ended in a collision."
COLLISIONS = (
    "{n} collisions. By the vehicle hit{doing} and whether the target lane's lag was drawn "
    "yielding (medians):"
)
COLLISIONS_DOING = ", what it was doing"
COLLISIONS_FOOTNOTE = (
    "– : no collision of the row had that value (the target lane had no lag vehicle when the "
    "gap was accepted). Every collision: `eval/collisions.csv`."
)

# --- the paper's claims (a)-(c) on the training curves ----------------------------------------
NO_CURVES = "(a)–(c) need the training curves (`metrics/episodes.npz`), which this run lacks."
WAITING_FOR_CURVES = "needs the training curves (`metrics/episodes.npz`)"
CURVE_MEASURES = (
    "The paper argues (a)–(c) from its training curves (Figs. 3, 4), so they are decided here "
    "on measures of each model's training curves (noise on; `jaxlc.evaluation.convergence`): "
    "`converged`, the episode from which the return's {window}-episode moving average stays "
    "within {band:.0f}% of its rise from its plateau (the mean of the last {plateau_episodes} "
    "episodes); `success95`, the first episode with 95% success over the last 100; "
    "`steps_rise`, where Fig. 4a's manoeuvre steps reach half their rise; `auc`, the area "
    "under the return curve normalised over the run; `plateau`, the final return. Each "
    'comparison "X better than Y" is decided on how far X is ahead of Y (the difference of '
    "the cells' means over seeds, positive on the paper's side: fewer episodes, more area or "
    "return) with its 95% bootstrap interval: *holds* above zero, *fails* below, *no practical "
    "difference* inside the margin (±{margin:.0f}% of the measure's axis: training episodes, "
    "the run's return range), undecided otherwise, and always below 5 seeds per cell."
)
CONVERGENCE_FOOTNOTE = "Every comparison on every measure: `eval/convergence.json`."


# --- the terminal's tables --------------------------------------------------------------------


def format_table(rows: Sequence[Row]) -> str:
    """Plain-text table of the evaluation rows for the terminal."""
    ends = OUTCOMES[1:] + OUTCOMES[:1]
    head = "policy                    seed    ep  perf  succ%   return  " + " ".join(
        f"{o[:4]:>4}" for o in ends
    )
    lines = [head]
    for r in rows:
        sr = "   -" if not defined(r.success_rate) else f"{100 * r.success_rate:5.1f}"
        ret = "      -" if not defined(r.avg_return) else f"{r.avg_return:8.1f}"
        counts = " ".join(f"{getattr(r, o):4d}" for o in ends)
        lines.append(
            f"{r.label[:26]:26} {'-' if r.seed is None else r.seed:>4} "
            f"{r.episode or '-':>5} {r.performed:5d} {sr:>6} {ret:>8}  {counts}"
        )
    return "\n".join(lines)


def _pct(v: Any, digits: int = 1) -> str:
    """A share for the terminal's table: a percentage without its sign, ``-`` undefined."""
    return percent(v, digits, unit="", missing=TERMINAL_DASH)


def format_heldout(rows: list[HeldoutRow]) -> str:
    """Plain-text table of held-out rows for the terminal."""
    lines = [
        "held-out policy            seed  lane ch.  succ% [95% CP]        coll  fail<%  all norms%"
    ]
    for r in rows:
        ci = f"[{_pct(r.success_lo)}, {_pct(r.success_hi)}]"
        lines.append(
            f"{str(r.label)[:26]:26} {'-' if r.seed is None else r.seed:>4} "
            f"{r.lane_changes:9d}  {_pct(r.success_rate, 2):>6} {ci:14} "
            f"{r.collision:5d}  {_pct(r.failure_bound, 2):>6}  {_pct(r.norm_all):>9}"
        )
    return "\n".join(lines)
