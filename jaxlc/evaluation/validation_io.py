"""What ``python -m jaxlc.validate`` writes to ``RUN_DIR/validate/`` (``write_outputs``; with
``--method ams``, ``ams_command`` and ``write_ams``), and a saved case run again (``replay``),
AMS's nearest misses read and run again (``misses``, ``rerun_miss``); its report section and
figures are ``jaxlc.report``'s."""

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
from jaxlc.sim.env import EnvParams
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
    chain: int = 1  # lane changes per case (``validation.program``); written only when > 1

    def to_json(self) -> str:
        models = [
            {f.name: getattr(r, f.name) for f in dataclasses.fields(r) if f.name != "cases"}
            | {"estimates": {k: e.to_dict() for k, e in r.estimates.items()}}
            for r in self.models
        ]
        for m in models:  # unchained: as every file before ``--chain``
            if m["places"] is None:
                del m["places"]
        doc = {f.name: getattr(self, f.name) for f in dataclasses.fields(self)}
        if self.chain == 1:  # as every file before ``--chain``
            del doc["chain"]
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
    """``validate/validate.json``, ``validate.csv`` and ``cases.json`` (``validate.md`` and
    ``scenes.png``: ``jaxlc.report``)."""
    out = validate_dir(args.run_dir, args.out)
    out.mkdir(parents=True, exist_ok=True)
    date = datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds")
    family = args.family if args.method == "is" else None
    doc = Validation(
        heldout.traffic_of(cfg.env), list(args.traffic), args.method, family, args.kind,
        args.chunk, args.seed, args.max_steps, round(peak), date, results, args.chain,
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
    (out / "cases.json").write_text(json.dumps([_case_dict(c) for c in cases], indent=1) + "\n")
    return out


def _case_dict(c: validation.Case) -> dict[str, Any]:
    """A failure as ``cases.json`` holds it: its place in a chain only where it has one."""
    d = dataclasses.asdict(c)
    return d if d["chain"] else {k: v for k, v in d.items() if k != "chain"}


def read_cases(out: Path) -> list[validation.Case]:
    """``cases.json``'s failures, highest weight first per model."""
    return [validation.Case(**c) for c in json.loads((out / "cases.json").read_text())]


def rerun(run_dir: Path, cfg: config.Config, doc: Validation, case: validation.Case) -> tuple:
    """A saved case run again (the same program, its key in every row of a chunk): the trace
    of its row, and whether its outcome and weight are the saved ones."""
    actor = None
    if case.checkpoint:
        actor = checkpoint.load(Path(run_dir) / case.checkpoint)[0]
    run = validation.program(cfg, doc.max_steps, case.method == "is", doc.chain)
    pol = validation.policies(cfg, actor, int(case.k))
    keys = jnp.tile(jnp.asarray(case.key, jnp.uint32)[None], (doc.chunk, 1))
    mix = case.proposal and Mixture.from_dict(case.proposal)
    o, trace = jax.device_get(run(mix and mix.proposal(case.component), pol, keys))
    if doc.chain > 1:  # its lane change of the chain: column chain * chunk, trace [chain]
        trace = jax.tree.map(lambda a: a[case.chain], trace)
        o = jax.tree.map(lambda a: a[:, case.chain * doc.chunk :], o)
    o, tr = columns(o), columns(trace)
    last = max(int(tr["frames"][0, 0]) - 1, 0)
    tr["side"] = np.asarray([1 if tr["y"][0, 0, 0] < tr["y"][0, 0, last] else -1])
    log_w = 0.0
    if mix:  # the chunk's weights, as the estimate computed them
        log_w = float(mix.log_weights(Record.unpack(o["tilt"][0].astype(np.float64)).log_r)[0])
    return tr, OUTCOMES[int(o["reason"][0][0])] == case.reason and log_w == case.log_w


def replay(run_dir: Path, index: int, out: Path | None = None) -> tuple:
    """``validate/cases.json``'s case ``index`` run again: ``(cfg, case, trace, same)``,
    ``same`` whether its outcome and weight are the saved ones bit for bit."""
    out = validate_dir(run_dir, out)
    if not (out / "cases.json").is_file():
        raise EvalError(f"{out / 'cases.json'} is missing; run python -m jaxlc.validate first")
    cases = read_cases(out)
    if not 0 <= index < len(cases):
        raise EvalError(f"--replay {index}: cases.json holds {len(cases)} cases")
    doc, case = Validation.read(out / "validate.json"), cases[index]
    cfg = heldout.in_traffic(RunDir(run_dir).load_config(), doc.traffic_overrides)
    tr, same = rerun(run_dir, cfg, doc, case)
    return cfg, case, tr, same


def misses(out: Path) -> list[tuple[ams.Estimate, ams.Miss]]:
    """``ams.json``'s nearest misses, policy after policy, nearest first."""
    if not (out / "ams.json").is_file():
        raise EvalError(f"{out / 'ams.json'} is missing; run python -m jaxlc.validate --method ams")
    doc = numbers.read(out / "ams.json", ams.Ams)
    if any(e.max_steps == 0 for e in doc.policies):  # written before the replay's fields
        raise EvalError(f"{out / 'ams.json'} cannot be replayed; run --method ams again")
    return [(e, m) for e in doc.policies for m in e.nearest]


def rerun_miss(run_dir: Path, est: ams.Estimate, miss: ams.Miss, exact: bool) -> tuple:
    """``ams.replay`` of a miss in the run's config and the estimate's traffic and policy, and
    the params it drew with."""
    cfg = heldout.in_traffic(RunDir(run_dir).load_config(), est.traffic)
    actor = checkpoint.load(Path(run_dir) / est.checkpoint)[0] if est.checkpoint else None
    pol = jax.tree.map(lambda x: x[0], validation.policies(cfg, actor, est.k))
    return *ams.replay(cfg, est, miss, pol, exact), EnvParams.from_config(cfg.env)


def ams_command(
    cfg: config.Config, rows: list[tuple], args: Any, out_dir: Path, peak: float
) -> list[ams.Estimate]:
    """``python -m jaxlc.validate --method ams``'s work on the chosen policies (``rows``:
    validate's ``model_rows``): each one's estimate printed, the files written (``write_ams``)."""
    results = []
    for actor, k, meta in rows:
        pol = validation.policies(cfg, actor, k)
        results.append(r := ams.estimate(cfg, meta, args, pol, peak))
        print(
            f"{r.label}: P(lane change with {args.kind} margin <= {args.margin:g}) {r.estimate:.3g}"
            f" [{r.lo:.3g}, {r.hi:.3g}] per case, {r.trajectories} cases simulated"
            f" ({r.env_steps:,} env steps with the warm-ups), {r.wall_s} s"
        )
        if any(r.extinct):
            print(
                f"  {sum(r.extinct)} of {len(r.extinct)} runs went extinct: their clones drew no"
                f" future of their own (distinct final paths {min(r.distinct):.1%} at least)"
            )
        least = r.nearest[0].margin if r.nearest else math.inf
        if args.margin < least < r.cap:  # as ``estimate`` put it on the curve
            at = min(r.curve, key=lambda c: abs(c.margin - least))
            print(
                f"  no run reached {args.margin:g}; the least margin reached {at.margin:.3g}: "
                f"P(margin <= it) {at.ams:.3g} [{at.ams_lo:.3g}, {at.ams_hi:.3g}] per case"
            )
    print(f"Wrote {write_ams(out_dir, results)}")
    return results


def write_ams(out_dir: Path, results: list[ams.Estimate]) -> Path:
    """``ams.json`` and ``ams_curve.csv`` (per policy and margin: AMS and crude MC with their
    95% intervals) in ``out_dir`` (``ams_curve.png``: ``jaxlc.report.plots.ams_curve``); the
    json's path."""
    numbers.write(out_dir / "ams.json", ams.Ams(results))
    rows = [dict(label=r.label, kind=r.kind, **c.as_dict()) for r in results for c in r.curve]
    numbers.write_csv(out_dir / "ams_curve.csv", rows)
    return out_dir / "ams.json"
