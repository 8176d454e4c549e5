"""README.md's reproduction verdict: each of the paper's claims, what the paper shows, and
its figures and verdict under ``configs/paper.toml`` and ``configs/default.toml``
(``jaxlc.evaluation.convergence``, ``jaxlc.evaluation.heldout``)."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

from benchmarks.tables.common import BENCHMARKS, load
from jaxlc import config
from jaxlc.evaluation import rare, validation
from jaxlc.evaluation.results import Claim
from jaxlc.evaluation.validation_io import Validation
from jaxlc.paper import claims
from jaxlc.paper.grid import is_best
from jaxlc.study.rundir import RunDir

PAPER_STUDY = BENCHMARKS / "study_paper_gpu_s10"  # configs/paper.toml, ten seeds per cell
VERDICT_STUDY = BENCHMARKS / "study_default_cpu_s10"  # configs/default.toml, ten seeds per cell
# Claim (d) by crude Monte Carlo, ④ of seeds 0-2: today's default at one in a million in the
# paper's traffic, then in the traffic that cuts in and brakes; configs/reactive.toml's there,
# then in the paper's traffic at one in a million.
_VALIDATE = BENCHMARKS / "validate_cpu_2026-11-27"
VALIDATED = {
    **{_VALIDATE / f"mc_{n}_m{m}": "" for n in ("3M", "hazards") for m in (3, 4, 5)},
    **{
        _VALIDATE / f"mc_reactive{n}_m{m}": " (`configs/reactive.toml`)"
        for n in ("", "_3M")
        for m in (3, 4, 5)
    },
}
# ④ of seed 0 (the first row above) on a GPU, one device call per key stream (seeds 0 and 1),
# pooled: independent lane changes, so their counts add.
POOLED = {
    " (GPU, key streams 0 and 1 pooled)": [
        BENCHMARKS / "bench_gpu_2026-11-27" / "gpu" / f"validate_keys{k}" for k in (0, 1)
    ],
}

# Measures counted in episodes (written whole, "ep"); the others are written to 3 figures.
_EPISODES = {"converged", "success95", "steps_rise"}


def _tag(claim: str) -> str:
    """``"(a, b) ④ converges …"`` -> ``"(a, b)"``."""
    return claim[: claim.index(")") + 1]


def _seeds(study: Path) -> str:
    n = len({m.seed for m in load(study, "convergence.json").models})
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


def _comparisons(study: Path, claim: Claim) -> str:
    """A claim's comparisons in a study on the measures it is decided by: each side's mean over
    seeds and, from 2 seeds on, the paper-side difference with its interval and the margin
    (``jaxlc.evaluation.convergence``)."""
    parts = []
    measures = claim.measures.split(", ")
    for c in load(study, "convergence.json").comparisons:
        if c.claim != claim.claim or c.measure not in measures:
            continue
        episodes = c.measure in _EPISODES
        fmt = "{:.0f}" if episodes else "{:.3g}"
        x, y = (("never" if v is None else fmt.format(v)) for v in (c.x_mean, c.y_mean))
        text = f"{c.measure}: {c.x} {x} vs {c.y} {y}{' ep' if episodes else ''}"
        if c.seeds > 1:  # every committed study's comparisons have their margins
            d, lo, hi, m = (fmt.format(v) for v in (c.diff, c.diff_lo, c.diff_hi, c.margin))
            text += f", {c.x} ahead by {d} [{lo}, {hi}] (margin ±{m})"
        parts.append(text)
    return "; ".join(parts)


def _claim_d(study: Path) -> tuple[str, str]:
    doc = load(study, "heldout.json")
    cell = next(c for c in doc.cells if is_best(c))
    text = (
        f"{cell.failures} failures ({cell.collisions} collisions) in "
        f"{cell.lane_changes:,} held-out lane changes; fails in < "
        f"{100 * cell.failure_bound:.2f}% (95%)"
    )
    return text, doc.claim_d.verdict


def verdict_table() -> str:
    """Each paper claim: what the paper shows, paper.toml's and default.toml's figures here,
    and both verdicts (``jaxlc.evaluation.convergence``, ``jaxlc.evaluation.heldout``)."""
    lines = [
        f"| claim | the paper shows | `paper.toml` here ({_seeds(PAPER_STUDY)}) | "
        f"`default.toml` here ({_seeds(VERDICT_STUDY)}{_unlike_default(VERDICT_STUDY)}) | "
        "verdict (paper.toml; default.toml) |",
        "|---|---|---|---|---|",
    ]
    paper_claims = {c.claim: c for c in load(PAPER_STUDY, "convergence.json").claims}
    for claim in load(VERDICT_STUDY, "convergence.json").claims:
        text = claim.claim
        lines.append(
            f"| {text} | {claims.SHOWS[_tag(text)]} | {_comparisons(PAPER_STUDY, claim)} | "
            f"{_comparisons(VERDICT_STUDY, claim)} | {paper_claims[text].verdict}; "
            f"{claim.verdict} |"
        )
    (p_text, p_verdict), (d_text, d_verdict) = _claim_d(PAPER_STUDY), _claim_d(VERDICT_STUDY)
    claim_d = load(VERDICT_STUDY, "heldout.json").claim_d.claim
    lines.append(
        f"| {claim_d} | {claims.SHOWS['(d)']} | {p_text} | {d_text} | {p_verdict}; {d_verdict} |"
    )
    return "\n".join(lines)


def validated_table() -> str:
    """Claim (d)'s strongest form: each validated policy's lane changes, its collisions and
    failures of any kind, each as a rate per lane change (a one-sided 95% bound where none
    occurred, else the estimate and its 95% interval), the traffic and the wall time
    (``python -m jaxlc.validate``'s ``validate.json``); a ``POOLED`` row adds the counts of
    one policy's runs on independent key streams."""
    lines = [
        "| policy | traffic | lane changes | collisions per lane change (95%) | "
        "failures of any kind per lane change (95%) | wall s (matmul peak) |",
        "|---|---|---|---|---|---|",
    ]

    def rate(e: rare.Estimate, ends: list[str]) -> str:  # ends: the kinds that occurred
        if e.failures == 0:
            return f"0 of them: < {e.upper_bound:.3g}"
        return f"{e.failures} ({', '.join(ends)}): {e.estimate:.2g} [{e.lo:.2g}, {e.hi:.2g}]"

    def row(meta: dict, trained: str, traffic: str, est: dict, walls: list[str]) -> str:
        ends = [k.replace("_", " ") + "s" for k in validation.ENDS if est[k].failures]
        return (
            f"| {meta['label']}, seed {meta['seed']}{trained} | {traffic} | "
            f"{est['failure'].lane_changes:,} | {rate(est['collision'], [])} | "
            f"{rate(est['failure'], ends)} | {' + '.join(walls)} |"
        )

    def wall(m: validation.Result, doc: Validation) -> str:  # one call's time, its peak
        return f"{m.wall_s:,.1f} ({doc.matmul_peak_gflops:,} GFLOP/s)"

    for folder, trained in VALIDATED.items():
        doc = Validation.read(folder / "validate.json")
        for m in doc.models:
            lines.append(row(m.meta, trained, doc.traffic, m.estimates, [wall(m, doc)]))
    for trained, folders in POOLED.items():
        docs = [Validation.read(f / "validate.json") for f in folders]
        ms = [d.models[0] for d in docs]  # one policy per call
        est = {
            k: rare.mc_estimate(
                sum(m.estimates[k].failures for m in ms),
                sum(m.estimates[k].lane_changes for m in ms),
            )
            for k in ("failure", *validation.ENDS)
        }
        walls = [wall(m, d) for m, d in zip(ms, docs, strict=True)]
        lines.append(row(ms[0].meta, trained, docs[0].traffic, est, walls))
    return "\n".join(lines)


BLOCKS = {"verdict": verdict_table, "claim-d-validated": validated_table}
