"""What an evaluation result is, and the one place that writes and reads it.

Every file the evaluation writes under ``RUN_DIR/eval/`` is a typed record here: a policy's
identity (``Policy``), its row on the protocol's cases (``Row``, ``eval.json``/``eval.csv``),
on the held-out lane changes (``HeldoutRow``, a cell of them ``HeldoutCell``, a collision
``Collision``, ``heldout.json``/``.csv``), the learning-speed study (``Speed``,
``Comparison``, ``convergence.json``), the statistics over seeds (``SeedCell``,
``Improvement``, ``Difference``, ``cells.json``) and a claim's verdict (``Claim``). A
record's fields are its columns in the files' order; ``own`` holds the columns a run adds
(its reward terms, measures registered with a held-out summary) where the field stands.
``read``/``write`` and ``csv_text``/``read_csv`` keep the bytes of every committed file
(NaN is JSON's null; a field an older file lacks reads as None).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field, fields
from typing import Any

import numpy as np

from jaxlc.evaluation.numbers import R, Record, defined, many, one, optional, own
from jaxlc.sim.reward import PAPER, REASONS

OUTCOMES = ("unfinished",) + REASONS[1:]  # index = reason code; 0: hit the step cap
PAPER_TERMS = tuple(t.name for t in PAPER)  # the default env.reward_terms
CELL_AXES = ("k", "memory", "actor_lr", "critic_lr", "noise_sigma")
CSV_ID = ("label", "model", "cell", "seed", "k", "memory", "episode")  # a row's CSV identity


class EvalError(Exception):
    """The evaluation cannot run; the message names the problem and the fix."""


# --------------------------------------------------------------------------- the protocol


@dataclass
class Policy(Record):
    """Which policy a row is: a model's checkpoint (its grid cell and seed), or the scripted
    controller (every field None)."""

    label: str | None = None
    model: int | None = None
    seed: int | None = None
    k: int | None = None
    memory: int | None = None
    episode: int | None = None
    cell: int | None = None
    actor_lr: float | None = None
    critic_lr: float | None = None
    noise_sigma: float | None = None
    checkpoint: str | None = None

    @property
    def axes(self) -> tuple:
        """Its grid cell: the values of ``CELL_AXES``."""
        return (self.k, self.memory, self.actor_lr, self.critic_lr, self.noise_sigma)


SCRIPTED = Policy(label="scripted controller")


@dataclass
class Row(Policy):
    """One policy on the protocol's cases: outcome counts (they add up to ``cases``) and its
    measures, each reward term of the run (``env.reward_terms``) among them (``terms``)."""

    cases: int = 0
    performed: int = 0
    unfinished: int = 0
    success: int = 0
    out_of_bounds: int = 0
    collision: int = 0
    timeout: int = 0
    no_gap: int = 0
    declined: int = 0
    success_rate: float | None = None
    avg_return: float | None = None
    duration_s: float | None = None
    peak_lat_acc: float | None = None
    peak_yaw_rate: float | None = None
    overshoot_m: float | None = None
    terms: dict[str, float] = own()
    timeout_offset_m: float | None = None
    timeout_heading: float | None = None
    timeout_yaw_rate: float | None = None


def measures(terms: Sequence[str] = PAPER_TERMS) -> tuple[str, ...]:
    """A row's measures; each reward term (``env.reward_terms``) is one, by its name."""
    names = [f.name for f in fields(Row)]
    at = names.index("terms")
    return (*names[names.index("success_rate") : at], *terms, *names[at + 1 :])


def eval_fields(terms: Sequence[str] = PAPER_TERMS) -> tuple[str, ...]:
    """The columns of ``eval.csv`` for a run whose reward has ``terms``."""
    return CSV_ID + ("cases", "performed") + OUTCOMES + measures(terms)


@dataclass
class EvalResult(Record):
    """``eval.json``: the setting, the cases (``before_rl``: how those without a lane change
    ended, the same for every policy) and one row per policy, the scripted controller first."""

    config_hash: str = ""
    cases: int = 0
    seed: int = 0
    max_steps: int = 0
    performed: int = 0
    left: int = 0
    right: int = 0
    before_rl: dict[str, int] = field(default_factory=dict)
    traced: list[int] = field(default_factory=list)
    success_box: dict[str, float] = field(default_factory=dict)
    rows: list[Row] = many(Row)


def summarise(
    out: dict[str, np.ndarray],
    dt: float,
    terms: Sequence[str] = PAPER_TERMS,
    metas: Sequence[Policy] | None = None,
) -> list[Row]:
    """One row per policy (``metas`` its identities): outcome counts (they add up to the
    cases) and the measures.

    Return and reward terms average over the cases that performed a lane change; duration,
    peak lateral acceleration, peak yaw rate and overshoot over the successful ones, which is
    what compares with human lane changes (~3-8 s). ``timeout_*`` are medians over the
    timeouts of the final |offset| (m), |heading| (rad) and |yaw rate| (rad/s), to set beside
    the success box."""
    rows = []
    for p in range(out["reason"].shape[0]):
        reason, perf = out["reason"][p], out["performed"][p]
        ok, late = reason == OUTCOMES.index("success"), reason == OUTCOMES.index("timeout")
        n_perf = int(perf.sum())
        policy = metas[p] if metas is not None else SCRIPTED

        def mean(key: str, where: np.ndarray, p: int = p) -> float:
            return mean_or_nan(out[key][p][where])

        rows.append(
            Row(
                **policy.as_dict(),
                cases=int(reason.size),
                performed=n_perf,
                **{name: int((reason == code).sum()) for code, name in enumerate(OUTCOMES)},
                success_rate=float(ok.sum() / n_perf) if n_perf else math.nan,
                avg_return=mean("ret", perf),
                duration_s=mean_or_nan(out["steps"][p][ok] * dt),
                peak_lat_acc=mean("peak_lat_acc", ok),
                peak_yaw_rate=mean("peak_yaw_rate", ok),
                overshoot_m=mean("overshoot", ok),
                terms={t: mean(t, perf) for t in terms},
                timeout_offset_m=_median_abs(out["final_offset"][p][late]),
                timeout_heading=_median_abs(out["final_psi"][p][late]),
                timeout_yaw_rate=_median_abs(out["final_omega"][p][late]),
            )
        )
    return rows


def mean_or_nan(values: np.ndarray) -> float:
    return float(np.mean(values)) if values.size else math.nan


def _median_abs(values: np.ndarray) -> float:
    return float(np.median(np.abs(values))) if values.size else math.nan


def final_rows(rows: Sequence[R]) -> list[R]:
    """Each model's row at its last evaluated checkpoint (the scripted row left out)."""
    last: dict[int, Any] = {}
    for r in rows:
        if r.model is not None and (r.model not in last or r.episode > last[r.model].episode):
            last[r.model] = r
    return [last[m] for m in sorted(last)]


def rank_key(row: Any) -> tuple[float, float]:
    """A row's (or a cell's) place, higher first: its success rate, then its average return;
    an undefined one (no lane change performed) below every number."""
    sr, ret = row.success_rate, row.avg_return
    return (sr if defined(sr) else -1.0, ret if defined(ret) else -math.inf)


def rank_models(rows: Sequence[Row]) -> list[Row]:
    """Final-checkpoint rows, best first (``rank_key``)."""
    return sorted(final_rows(rows), key=rank_key, reverse=True)


# --------------------------------------------------------------------------- held-out


@dataclass
class CellId(Record):
    """A grid cell: its label and the values of ``CELL_AXES``."""

    label: str | None = None
    k: int | None = None
    memory: int | None = None
    actor_lr: float | None = None
    critic_lr: float | None = None
    noise_sigma: float | None = None


@dataclass
class HeldoutRow(Policy):
    """One policy on the held-out lane changes (``jaxlc.evaluation.heldout.model_row``): how
    they ended, rates with 95% Clopper-Pearson intervals, means over the successful ones,
    5th percentiles of TTC and headway, each norm's share (``safety.NORMS``), the share
    critical per vehicle, the traffic's hazards met, then each registered measure's summary
    (``measures``; an older file's retired columns land there too)."""

    lane_changes: int = 0
    success: int = 0
    out_of_bounds: int = 0
    collision: int = 0
    timeout: int = 0
    unfinished: int = 0
    success_rate: float | None = None
    success_lo: float | None = None
    success_hi: float | None = None
    failure_bound: float | None = None
    collision_rate: float | None = None
    collision_lo: float | None = None
    collision_hi: float | None = None
    duration_s: float | None = None
    lcm_s: float | None = None
    lcm_start_s: float | None = None
    peak_lat_acc: float | None = None
    peak_lat_jerk: float | None = None
    peak_long_acc: float | None = None
    peak_long_jerk: float | None = None
    min_ttc_s: float | None = None
    min_thw_s: float | None = None
    norm_lcm_s: float | None = None
    norm_peak_lat_acc: float | None = None
    norm_peak_lat_jerk: float | None = None
    norm_min_ttc_s: float | None = None
    norm_min_thw_s: float | None = None
    norm_all: float | None = None
    ttc_crit_lead: float | None = None
    ttc_crit_lag: float | None = None
    ttc_crit_own: float | None = None
    thw_crit_lead: float | None = None
    thw_crit_lag: float | None = None
    thw_crit_own: float | None = None
    cut_ins: int | None = None
    met_cut_in: int | None = None
    brakes_near: int | None = None
    met_braking: int | None = None
    measures: dict[str, float] = own()


@dataclass
class HeldoutCell(CellId):
    """A grid cell's held-out models (``heldout.cell_rows``): mean success over its seeds
    with its interval (``interval`` says which), pooled failures and collisions with their
    one-sided bounds, the share inside every norm, the hazards met."""

    seeds: int = 0
    lane_changes: int = 0
    success_mean: float | None = None
    success_lo: float | None = None
    success_hi: float | None = None
    interval: str = ""
    failures: int = 0
    failure_bound: float | None = None
    collisions: int = 0
    collision_rate: float | None = None
    collision_bound: float | None = None
    models_without_failure: int = 0
    norm_all: float | None = None
    cut_ins: int | None = None
    met_cut_in: int | None = None
    brakes_near: int | None = None
    met_braking: int | None = None


@dataclass
class Collision(Record):
    """One held-out collision: the vehicle hit and what it was doing, the ego's speed and time
    into the manoeuvre, the gaps and lag speed when the gap was accepted."""

    label: str | None = None
    model: int | None = None
    seed: int | None = None
    episode: int | None = None
    case: int = 0
    partner: str = ""
    hazard: str | None = None
    yielding: bool = False
    hit_speed: float | None = None
    time_s: float | None = None
    accept_v: float | None = None
    accept_lead_gap: float | None = None
    accept_lag_gap: float | None = None
    accept_lag_v: float | None = None


@dataclass
class Claim(Record):
    """One of the paper's claims (``jaxlc.paper.claims``) as this run decides it."""

    claim: str = ""
    paper: str | None = optional()
    measures: str | None = optional()  # the key measures it is decided on
    figures: str = ""
    verdict: str = "n/a"


@dataclass
class Norm(Record):
    """A norm of a lane change (``safety.NORMS``): its measure below (or at least) ``bound``."""

    measure: str = ""
    bound: float = 0.0
    below: bool = True
    source: str = ""


@dataclass
class Heldout(Record):
    """``heldout.json``: the lane changes, the norms, per model and per cell, claim (d), every
    collision; ``measures`` names the registered measures with a held-out summary (none: the
    key is left out, as in every older file)."""

    config_hash: str = ""
    seed: int = 0
    key_stream: str = ""
    cases: int = 0
    lane_changes: int = 0
    norms: list[Norm] = many(Norm)
    conflicts_counted: str | None = None
    traffic: str | None = None
    traffic_overrides: list[str] | None = None
    rows: list[HeldoutRow] = many(HeldoutRow)
    cells: list[HeldoutCell] = many(HeldoutCell)
    claim_d: Claim | None = one(Claim)
    collisions: list[Collision] = many(Collision)
    measures: list[str] | None = optional()


CHOICE = "choice.json"  # under RUN_DIR/eval/: each model's chosen checkpoint


@dataclass
class Choice(Record):
    """``eval/choice.json`` (``python -m jaxlc.evaluate RUN --choose``): per model (its index as
    text) the episode of the checkpoint chosen and, per candidate episode, its failed lane
    changes (not successes) over the ``settings``, ``lane_changes`` each on held-out
    ``seed``."""

    seed: int = 0
    lane_changes: int = 0
    settings: list[str] = field(default_factory=list)
    episode: dict[str, int] = field(default_factory=dict)
    failures: dict[str, dict[str, int]] = field(default_factory=dict)

    def table(self) -> str:
        """One line per model: its candidates' failures, the chosen episode marked."""
        head = f"failed of {self.lane_changes} x {len(self.settings)} lane changes (* chosen)"
        lines = [f"model  {head}"]
        for m, by in self.failures.items():
            ep = str(self.episode[m])
            cells = [f"{e}: {n}{'*' if e == ep else ''}" for e, n in by.items()]
            lines.append(f"{m:>5}  " + ", ".join(cells))
        return "\n".join(lines)


def heldout_fields(measures: Sequence[str] = ()) -> tuple[str, ...]:
    """``heldout.csv``'s columns: the identity, ``HeldoutRow``'s, then ``measures``'."""
    own_ = [f.name for f in fields(HeldoutRow)[len(fields(Policy)) :] if f.name != "measures"]
    # the CSV has the longitudinal peaks after the TTC and headway percentiles (the JSON before)
    longitudinal = ["peak_long_acc", "peak_long_jerk"]
    own_ = [n for n in own_ if n not in longitudinal]
    at = own_.index("min_thw_s") + 1
    return CSV_ID + tuple(own_[:at] + longitudinal + own_[at:]) + tuple(measures)
