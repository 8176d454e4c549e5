"""What ``python -m jaxlc.validate`` writes: ``RUN_DIR/validate/`` (``write_outputs``), the
report's section (``report_section``), each failure kind's scene (``scenes_figure``), a
saved case replayed as a GIF (``replay_case``); AMS's nearest misses at their closest moment
(``misses_figure``) and one replayed as a GIF (``replay_miss``)."""

from __future__ import annotations

import dataclasses
import datetime
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc import config
from jaxlc.evaluation import ams, heldout, numbers, rare, validation
from jaxlc.evaluation.cases import columns
from jaxlc.evaluation.mixture import Mixture
from jaxlc.evaluation.numbers import csv_text
from jaxlc.evaluation.proposal import Record
from jaxlc.evaluation.results import OUTCOMES, EvalError
from jaxlc.sim.env import CRUISE, GAP, RL, WAIT, EnvParams
from jaxlc.sim.render import render_frame
from jaxlc.study import checkpoint
from jaxlc.study.rundir import RunDir

FIELDS = ("label", "model", "seed", "method", "kind", "estimate", "lo", "hi", "upper_bound")
FIELDS += ("rel_halfwidth", "ess", "failures", "lane_changes", "wall_s", "lane_changes_per_s")
FIELDS += ("matmul_peak_gflops",)


def validate_dir(run_dir: Path, out: Path | None = None) -> Path:
    """Where the validation of ``run_dir`` goes: ``out``, or ``RUN_DIR/validate``."""
    return Path(out) if out is not None else Path(run_dir) / "validate"


@dataclass
class Validation:
    """``validate.json``: the setting and each model's ``validation.Result`` (its cases apart,
    in ``cases.json``); ``family`` None with crude MC (and absent from older files)."""

    traffic: str
    traffic_overrides: list[str]
    method: str
    family: str | None
    kind: str
    chunk: int
    seed: int
    max_steps: int
    matmul_peak_gflops: int
    date: str
    models: list[validation.Result]

    def to_json(self) -> str:
        models = [
            {f.name: getattr(r, f.name) for f in dataclasses.fields(r) if f.name != "cases"}
            | {"estimates": {k: e.to_dict() for k, e in r.estimates.items()}}
            for r in self.models
        ]
        doc = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        return json.dumps(doc | {"models": models}, indent=1, default=str) + "\n"

    @classmethod
    def read(cls, path: Path) -> Validation:
        """A ``validate.json`` (older ones: no ``defensive`` with crude MC)."""
        doc = json.loads(Path(path).read_text())
        models = [
            validation.Result(**{"defensive": 0.0, **m, "estimates": {
                k: rare.Estimate(**e) for k, e in m["estimates"].items()}})
            for m in doc.pop("models")
        ]  # fmt: skip
        return cls(**{"family": None, **doc, "models": models})


def write_outputs(
    args: Any, cfg: config.Config, results: list[validation.Result], peak: float
) -> Path:
    """``validate/validate.json``, ``validate.csv``, ``cases.json``, ``validate.md`` and the
    figure."""
    out = validate_dir(args.run_dir, args.out)
    out.mkdir(parents=True, exist_ok=True)
    date = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    family = args.family if args.method == "is" else None
    doc = Validation(
        heldout.traffic_of(cfg.env), list(args.traffic), args.method, family, args.kind,
        args.chunk, args.seed, args.max_steps, round(peak), date, results,
    )  # fmt: skip
    (out / "validate.json").write_text(doc.to_json())
    more = {"matmul_peak_gflops": round(peak)}
    rows = [
        r.meta | e.to_dict() | {"method": r.method, "kind": kind, "wall_s": r.wall_s}
        | {"lane_changes_per_s": r.lane_changes_per_s} | more
        for r in results
        for kind, e in r.estimates.items()
    ]  # fmt: skip
    checkpoint.write_text_atomic(out / "validate.csv", csv_text(rows, FIELDS))
    cases = [c for r in results for c in r.cases]
    (out / "cases.json").write_text(
        json.dumps([dataclasses.asdict(c) for c in cases], indent=1) + "\n"
    )
    (out / "validate.md").write_text("\n".join(report_section(args.run_dir, out)) + "\n")
    scenes_figure(args.run_dir, out, cfg, doc, cases)
    return out


def read_cases(out: Path) -> list[validation.Case]:
    """``cases.json``'s failures, highest weight first per model."""
    return [validation.Case(**c) for c in json.loads((out / "cases.json").read_text())]


_FAMILY = {"mixture": " (a mixture of one-role braking tilts)"}


def _sci(v: Any) -> str:
    return "-" if v is None or not math.isfinite(v) else f"{v:.3g}"


def report_section(run_dir: Path, out: Path | None = None) -> list[str]:
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


def scenes_figure(
    run_dir: Path, out: Path, cfg: config.Config, doc: Validation, cases: list[validation.Case]
) -> Path | None:
    """``scenes.png``: per failure kind, its highest-weight saved case replayed, the scene at
    its last step (the ego red, the gap's lead and lag green)."""
    kinds = [k for k in validation.KINDS if any(k in c.kinds for c in cases)]
    if not kinds:
        return None
    from jaxlc.report.plots import _save, plt

    p = EnvParams.from_config(cfg.env)
    fig, axes = plt.subplots(len(kinds), 1, figsize=(8, 1.3 * len(kinds) + 0.3), squeeze=False)
    for ax, kind in zip(axes[:, 0], kinds, strict=True):
        case = next(c for c in cases if kind in c.kinds)  # highest weight first
        tr, _ = _rerun(run_dir, cfg, doc, case)
        n = sum(kind in c.kinds for c in cases)
        title = f"{kind} ({n} saved): {case.label}, case {case.index}, {case.reason}, "
        _draw(ax, tr, max(int(tr["frames"][0, 0]) - 1, 0), p, title + _log10_w(case))
    return _save(fig, out / "scenes.png")


def _log10_w(case: validation.Case) -> str:
    return f"log10 w = {case.log_w / math.log(10):.2f}"


def _draw(ax: Any, tr: dict, frame: int, p: EnvParams, title: str) -> None:
    """A saved case's scene at ``frame`` (the ego red, the gap's lead and lag green)."""
    from jaxlc.report.plots_scenes import draw_scene

    draw_scene(ax, tr, 0, 0, frame, p)
    ax.set_axis_off()
    ax.set_title(title, fontsize=8, loc="left")


def _rerun(run_dir: Path, cfg: config.Config, doc: Validation, case: validation.Case) -> tuple:
    """A saved case run again (the same program, its key in every row of a chunk): the trace
    of its row, and whether its outcome and weight are the saved ones."""
    actor = None
    if case.checkpoint:
        actor = checkpoint.load(Path(run_dir) / case.checkpoint)[0]
    run = validation.program(cfg, doc.max_steps, case.method == "is")
    pol = validation.policies(cfg, actor, int(case.k))
    keys = jnp.tile(jnp.asarray(case.key, jnp.uint32)[None], (doc.chunk, 1))
    mix = case.proposal and Mixture.from_dict(case.proposal)
    o, trace = jax.device_get(run(mix and mix.proposal(case.component), pol, keys))
    o, tr = columns(o), columns(trace)
    last = max(int(tr["frames"][0, 0]) - 1, 0)
    tr["side"] = np.asarray([1 if tr["y"][0, 0, 0] < tr["y"][0, 0, last] else -1])
    log_w = 0.0
    if mix:  # the chunk's weights, as the estimate computed them
        log_w = float(mix.log_weights(Record.unpack(o["tilt"][0].astype(np.float64)).log_r)[0])
    return tr, OUTCOMES[int(o["reason"][0][0])] == case.reason and log_w == case.log_w


def replay_case(run_dir: Path, index: int, out: Path | None = None) -> tuple[Path, bool]:
    """Run ``validate/cases.json``'s case ``index`` again and draw it as
    ``validate/case_INDEX.gif``; returns the path and whether the outcome and weight are the
    saved ones bit for bit."""
    out = validate_dir(run_dir, out)
    if not (out / "cases.json").is_file():
        raise EvalError(f"{out / 'cases.json'} is missing; run python -m jaxlc.validate first")
    cases = read_cases(out)
    if not 0 <= index < len(cases):
        raise EvalError(f"--replay {index}: cases.json holds {len(cases)} cases")
    doc, case = Validation.read(out / "validate.json"), cases[index]
    cfg = heldout.in_traffic(RunDir(run_dir).load_config(), doc.traffic_overrides)
    tr, same = _rerun(run_dir, cfg, doc, case)
    return _gif(out / f"case_{index}.gif", tr, cfg, case), same


def _gif(path: Path, tr: dict, cfg: config.Config, case: validation.Case) -> Path:
    from jaxlc.report.plots import PillowWriter, plt

    p = EnvParams.from_config(cfg.env)
    fig, ax = plt.subplots(figsize=(8, 1.5))
    writer = PillowWriter(fps=10)
    with writer.saving(fig, path, dpi=90):
        for f in range(max(int(tr["frames"][0, 0]), 1)):
            ax.clear()
            title = f"{case.label}  t = {f * p.dt:4.1f} s  {case.reason}  "
            _draw(ax, tr, f, p, title + _log10_w(case))
            writer.grab_frame()
    plt.close(fig)
    return path


PHASES = {WAIT: "waiting", CRUISE: "cruise", GAP: "gap search", RL: "lane change"}


def _misses(out: Path) -> list[tuple[ams.Estimate, ams.Miss]]:
    """``ams.json``'s nearest misses, policy after policy, nearest first."""
    if not (out / "ams.json").is_file():
        raise EvalError(f"{out / 'ams.json'} is missing; run python -m jaxlc.validate --method ams")
    doc = numbers.read(out / "ams.json", ams.Ams)
    if any(e.max_steps == 0 for e in doc.policies):  # written before the replay's fields
        raise EvalError(f"{out / 'ams.json'} cannot be replayed; run --method ams again")
    return [(e, m) for e in doc.policies for m in e.nearest]


def _replay_miss(run_dir: Path, est: ams.Estimate, miss: ams.Miss, exact: bool) -> tuple:
    """``ams.replay`` of a miss in the run's config and the estimate's traffic and policy, and
    the params it drew with."""
    cfg = heldout.in_traffic(RunDir(run_dir).load_config(), est.traffic)
    actor = checkpoint.load(Path(run_dir) / est.checkpoint)[0] if est.checkpoint else None
    pol = jax.tree.map(lambda x: x[0], validation.policies(cfg, actor, est.k))
    return *ams.replay(cfg, est, miss, pol, exact), EnvParams.from_config(cfg.env)


def _miss_title(est: ams.Estimate, miss: ams.Miss, f: int, p: EnvParams, phase: int) -> str:
    unit = "s" if est.kind == "timeout" else "m"
    return (f"{est.label}, run {miss.repeat}: {est.kind} margin {miss.margin:.3f} {unit}; "
            f"t = {(f + 1) * p.dt:.1f} s, {PHASES[int(phase)]}")  # fmt: skip


def misses_figure(run_dir: Path, out: Path | None = None) -> Path | None:
    """``ams_misses.png``: each of ``ams.json``'s nearest misses replayed, its scene at its
    closest moment (the first step its score path reached its top: the ego red)."""
    out = validate_dir(run_dir, out)
    misses = _misses(out)
    if not misses:
        return None
    from jaxlc.report.plots import _save, plt

    fig, axes = plt.subplots(len(misses), 1, figsize=(8, 1.2 * len(misses) + 0.2), squeeze=False)
    for ax, (est, miss) in zip(axes[:, 0], misses, strict=True):
        _, path, states, p = _replay_miss(run_dir, est, miss, exact=False)
        f = int(np.argmax(path))
        ax.imshow(render_frame(jax.tree.map(lambda x, f=f: x[f], states), p))
        ax.set_axis_off()
        ax.set_title(_miss_title(est, miss, f, p, states.ego.phase[f]), fontsize=8, loc="left")
    return _save(fig, out / "ams_misses.png")


def replay_miss(run_dir: Path, index: int, out: Path | None = None) -> tuple[Path, bool]:
    """``ams.json``'s nearest miss ``index`` (``_misses``' order) run again from its key chain
    and drawn as ``validate/ams_miss_INDEX.gif`` from 3 s before its gap search on (at most
    300 frames, in real time); returns the path and whether its margin is the saved one bit
    for bit."""
    out = validate_dir(run_dir, out)
    misses = _misses(out)
    if not 0 <= index < len(misses):
        raise EvalError(f"--replay {index}: ams.json holds {len(misses)} nearest misses")
    est, miss = misses[index]
    margin, path, states, p = _replay_miss(run_dir, est, miss, exact=True)
    from jaxlc.report.plots import PillowWriter, plt

    phase = np.asarray(states.ego.phase)
    start = max(int(np.argmax(phase >= GAP)) - int(round(3.0 / p.dt)), 0)
    stride = max(1, -(-(len(phase) - start) // 300))
    fig, ax = plt.subplots(figsize=(8, 1.3))
    writer, gif = PillowWriter(fps=1.0 / (p.dt * stride)), out / f"ams_miss_{index}.gif"
    with writer.saving(fig, gif, dpi=90):
        for f in range(start, len(phase), stride):
            ax.clear()
            ax.imshow(render_frame(jax.tree.map(lambda x, f=f: x[f], states), p))
            ax.set_axis_off()
            so_far = f"so far {-path[f]:.2f}" if path[f] > -est.cap else "not yet"
            title = _miss_title(est, miss, f, p, phase[f]) + f"; margin {so_far}"
            ax.set_title(title, fontsize=7, loc="left")
            writer.grab_frame()
    plt.close(fig)
    return gif, margin == miss.margin


def ams_command(
    cfg: config.Config, rows: list[tuple], args: Any, out_dir: Path, peak: float
) -> int:
    """``python -m jaxlc.validate --method ams``'s work on the chosen policies (``rows``:
    validate's ``model_rows``): each one's estimate printed, the files written."""
    results = []
    for actor, k, meta in rows:
        pol = validation.policies(cfg, actor, k)
        results.append(r := ams.estimate(cfg, meta, args, pol, peak))
        print(
            f"{r.label}: P(lane change with {args.kind} margin <= {args.margin:g}) {r.estimate:.3g}"
            f" [{r.lo:.3g}, {r.hi:.3g}] per case, {r.trajectories} cases simulated, {r.wall_s} s"
        )
        if any(r.extinct):
            print(
                f"  {sum(r.extinct)} of {len(r.extinct)} runs went extinct: their clones drew no"
                f" future of their own (distinct final paths {min(r.distinct):.0%} at least)"
            )
    print(f"Wrote {write_ams(out_dir, results)}")
    return 0


def write_ams(out_dir: Path, results: list[ams.Estimate]) -> Path:
    """``ams.json``, ``ams_curve.csv`` (per policy and margin: AMS and crude MC with their
    95% intervals) and ``ams_curve.png`` in ``out_dir``; the json's path."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    numbers.write(out_dir / "ams.json", ams.Ams(results))
    rows = [dict(label=r.label, kind=r.kind, **c.as_dict()) for r in results for c in r.curve]
    numbers.write_csv(out_dir / "ams_curve.csv", rows)
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
    fig.savefig(out_dir / "ams_curve.png", dpi=120)
    plt.close(fig)
    return out_dir / "ams.json"
