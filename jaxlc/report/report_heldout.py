"""``report.md``'s held-out sections: per cell and per model against the norms (a measure
registered with a held-out summary adds its column), and every collision tallied by the
vehicle hit (``eval/heldout.json``, ``jaxlc.evaluation.heldout``); ``python -m
jaxlc.validate``'s section (``validate/validate.json``, also its ``validate.md``); how
close to failure, by AMS (``validate/ams.json``, ``ams_section``)."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc.evaluation import ams
from jaxlc.evaluation.numbers import defined, fixed, read
from jaxlc.evaluation.results import Collision, Heldout, HeldoutRow
from jaxlc.evaluation.validation_io import Validation, validate_dir
from jaxlc.report import report_text as text
from jaxlc.report.report_text import EVERY_STEP, percent

# How close to each failure (heldout.MARGIN_KEYS), where the rows have them (older: none).
MARGINS = {
    "margin_gap": "clearance m",
    "margin_time": "time left s",
    "margin_border": "to border m",
}
COLLISION_MEDIANS = ("hit_speed", "time_s", "accept_lag_gap", "accept_lag_v", "accept_v")


def _heldout_tables(doc: Heldout) -> list[str]:
    """Per cell and per model: outcomes with intervals, then the norms."""
    lines = [
        "| cell | seeds | lane changes | success, mean [interval] | failures | failure "
        "< (95%) | collisions | collision rate | inside every norm |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for c in doc.cells:
        ci = f"{percent(c.success_mean)} [{percent(c.success_lo)}, {percent(c.success_hi)}]"
        lines.append(
            f"| {c.label} | {c.seeds} | {c.lane_changes} | {ci} | {c.failures} | "
            f"{fixed(100 * c.failure_bound)}% | {c.collisions} | "
            f"{fixed(100 * c.collision_rate, '.2f')}% | {percent(c.norm_all)} |"
        )
    how = sorted({c.interval for c in doc.cells})
    lines += ["", f"Cell intervals: {'; '.join(how)}.", ""]
    norms = [n.measure for n in doc.norms]
    extra = doc.measures or []  # measures registered with a held-out summary
    margins = [m for m in MARGINS if any(f"{m}_p5" in r.measures for r in doc.rows)]
    lines += [
        "| model | seed | success [95% CP] | out of bounds | collision | timeout | "
        "duration s | R79 manoeuvre s | peak lat. acc. m/s² | peak lat. jerk m/s³ | "
        "peak long. acc. m/s² | peak long. jerk m/s³ | min TTC s, 5th pct. | "
        "min THW s, 5th pct. | "
        + " | ".join(f"{m} ok" for m in norms)
        + " | all norms |"
        + "".join(f" {MARGINS[m]}, 5th / 50th pct. |" for m in margins)
        + "".join(f" {m} |" for m in extra),
        "|---" * (15 + len(norms) + len(margins) + len(extra)) + "|",
    ]
    for r in doc.rows:
        lines.append(
            f"| {r.label} | {'' if r.seed is None else r.seed} | {percent(r.success_rate)} "
            f"[{percent(r.success_lo)}, {percent(r.success_hi)}] "
            f"| {r.out_of_bounds} | {r.collision} | {r.timeout} | "
            f"{fixed(r.duration_s)} | {fixed(r.lcm_s)} | {fixed(r.peak_lat_acc)} | "
            f"{fixed(r.peak_lat_jerk)} | {fixed(r.peak_long_acc)} | {fixed(r.peak_long_jerk)} | "
            f"{_tail(r, r.min_ttc_s)} | {_tail(r, r.min_thw_s)} | "
            + " | ".join(percent(r.get(f"norm_{m}")) for m in norms)
            + f" | {percent(r.norm_all)} |"
            + "".join(
                f" {_tail(r, r.measures.get(m + '_p5'))} / {_tail(r, r.measures.get(m + '_p50'))} |"
                for m in margins
            )
            + "".join(f" {fixed(r.measures.get(m))} |" for m in extra)
        )
    return lines


def _tail(r: HeldoutRow, value: float | None) -> str:
    """A TTC or headway percentile; JSON holds an infinite one (no closing) as null."""
    return "∞" if value is None and r.lane_changes else fixed(value)


def collision_tally(doc: Heldout) -> list[str]:
    hits = doc.collisions
    if not hits:
        return [text.NO_COLLISIONS, ""]
    hazards = any(h.hazard is not None for h in hits)  # the traffic has hazards
    groups: dict[tuple[str, str, bool], list[Collision]] = {}
    for h in hits:
        groups.setdefault((h.partner, h.hazard or "", h.yielding), []).append(h)
    lines = [
        text.COLLISIONS.format(n=len(hits), doing=text.COLLISIONS_DOING if hazards else ""),
        "",
        "| vehicle hit |"
        + (" it was |" if hazards else "")
        + " lag yields | collisions | ego speed m/s | time into manoeuvre s | "
        "lag gap at acceptance m | lag speed at acceptance m/s | ego speed at acceptance m/s |",
        "|---|---|---|---|---|---|---|---|" + ("---|" if hazards else ""),
    ]
    for (who, hz, ylds), hs in sorted(groups.items(), key=lambda kv: -len(kv[1])):
        med = {k: _median([getattr(h, k) for h in hs]) for k in COLLISION_MEDIANS}
        lines.append(
            f"| {who.replace('_', ' ')} | "
            + (f"{hz.replace('_', ' ')} | " if hazards else "")
            + f"{'yes' if ylds else 'no'} | {len(hs)} | "
            + " | ".join(fixed(med[k], ".1f") for k in COLLISION_MEDIANS)
            + " |"
        )
    return lines + ["", text.COLLISIONS_FOOTNOTE, ""]


def _median(values: list[Any]) -> float:
    """Median of the defined values (a record holds None where there was no such vehicle);
    NaN, printed as a dash, when none is."""
    kept = [float(v) for v in values if defined(v)]
    return float(np.median(kept)) if kept else math.nan


def section(doc: Heldout | None, tag: str = "") -> list[str]:
    """``eval/heldout.json``'s content (``doc``; None: the run has no held-out evaluation),
    or that of ``eval/heldout_TAG/heldout.json``, driven in another traffic."""
    if doc is None:
        return []
    norms = "; ".join(n.source for n in doc.norms)
    where = f" in another traffic (`{tag}`)" if tag else ""
    overrides = ", ".join(f"`{o}`" for o in doc.traffic_overrides or [])
    return [
        f"## Held-out lane changes{where}",
        "",
        f"Measured in {doc.traffic or 'the training traffic'}"
        + (f" (overrides {overrides})." if overrides else ".")
        + (text.HELDOUT_HAZARDS if overrides else ""),
        "",
        text.HELDOUT.format(
            lane_changes=doc.lane_changes,
            cases=doc.cases,
            key_stream=doc.key_stream,
            norms=norms,
            counted=doc.conflicts_counted or EVERY_STEP,
        ),
        "",
        text.CLAIM_D.format(figures=doc.claim_d.figures, verdict=doc.claim_d.verdict),
        "",
        *_heldout_tables(doc),
        "",
        "### Collisions",
        "",
        *collision_tally(doc),
    ]


_FAMILY = {"mixture": " (a mixture of one-role braking tilts)"}


def _sci(v: Any) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.3g}"


def validation_section(run_dir: Path, out: Path | None = None) -> list[str]:
    """``report.md``'s section: per model and kind, the probability per lane change and its
    95% interval; nothing when the run has not been validated."""
    path = validate_dir(run_dir, out) / "validate.json"
    if not path.is_file():
        return []
    doc = Validation.read(path)
    lines = [
        "## How rarely it fails (`python -m jaxlc.validate`)",
        "",
        f"{doc.method.upper()}{_FAMILY.get(doc.family, '')} in {doc.traffic}; {doc.date}, "
        f"matmul peak {doc.matmul_peak_gflops} GFLOP/s. Probability per lane change, 95% "
        "interval, relative half-width, effective sample size; `validate/validate.json`.",
        "",
        "| policy | kind | estimate | 95% interval | rel. half-width | ESS | lane changes | s |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for m in doc.models:
        for kind, e in m.estimates.items():
            if e.failures == 0 and kind != doc.kind:
                continue
            lines.append(
                f"| {m.meta['label']} | {kind} | {_sci(e.estimate)} | [{_sci(e.lo)}, "
                f"{_sci(e.hi)}] | {_sci(e.rel_halfwidth)} | {_sci(e.ess)} | "
                f"{e.lane_changes} | {m.wall_s} |"
            )
    return lines + [""]


def ams_section(run_dir: Path) -> list[str]:
    """How close to failure (``python -m jaxlc.validate --method ams``): per policy the
    exceedance curve's figure and its table, P(margin <= m) per case by AMS beside crude MC on
    the runs' initial cases, each with its 95% interval; nothing without ``validate/ams.json``."""
    path = Path(run_dir) / "validate" / "ams.json"
    if not path.is_file():
        return []
    doc = read(path, ams.Ams)
    lines = ["## How close to failure (`python -m jaxlc.validate --method ams`)", ""]
    for e in doc.policies:
        unit = "s" if e.kind == "timeout" else "m"
        noisy = f" under the training's exploration noise (sigma {e.noise:g})" if e.noise else ""
        lines += [
            f"{e.label}{noisy}: P(a lane change with {e.kind} margin <= m) per case started, by "
            f"adaptive multilevel splitting: {len(e.repeats)} runs of {e.particles} cases, "
            f"{e.kill:g} killed per round, Cox's 95% interval over the runs; crude Monte Carlo "
            f"on the runs' initial cases beside it (Clopper-Pearson). At m = {e.margin:g} "
            f"{unit}: {_sci(e.estimate)} [{_sci(e.lo)}, {_sci(e.hi)}]; {e.trajectories} cases "
            f"simulated, {e.wall_s} s, matmul peak {e.matmul_peak_gflops:.0f} GFLOP/s.",
            "",
            f"| margin m, {unit} | AMS | 95% interval | crude MC | 95% interval | cases <= m |",
            "|---|---|---|---|---|---|",
        ]
        for c in e.curve:
            lines.append(
                f"| {c.margin:.3g} | {_sci(c.ams)} | [{_sci(c.ams_lo)}, {_sci(c.ams_hi)}] | "
                f"{_sci(c.crude)} | [{_sci(c.crude_lo)}, {_sci(c.crude_hi)}] | {c.crude_n} |"
            )
        lines.append("")
    lines.append("![The exceedance curve](validate/ams_curve.png)")
    if (path.parent / "ams_misses.png").is_file():
        lines += ["", "The nearest misses at their closest moment (`--replay K` draws one):", ""]
        lines.append("![The nearest misses](validate/ams_misses.png)")
    return lines + [""]
