"""``python -m jaxlc.validate RUN_DIR``: how rarely a policy fails, per lane change.

    python -m jaxlc.validate runs/s3 --model ④ --method is --lane-changes 100000
    python -m jaxlc.validate runs/s3 --model scripted --method mc --rel-halfwidth 0.2 \\
        --traffic env.braking=true
    python -m jaxlc.validate runs/s3 --replay 0        # validate/cases.json's first, a GIF
    python -m jaxlc.validate runs/s3 --method ams --replay 0   # ams.json's nearest miss

Drives each chosen policy (``--model``: an index, a label, a paper tag such as ④, ``all`` or
``scripted``; each seed's checkpoint of a tag) through up to ``--lane-changes`` held-out-style
lane changes, by crude Monte Carlo (``mc``) or importance sampling (``is``: the traffic around
the ego drawn from a proposal fitted by the cross-entropy method, each lane change weighted by
its likelihood ratio; ``--family mixture``: a mixture of one-role braking tilts,
``jaxlc.evaluation.mixture``), stopping early once the ``--kind``'s relative half-width reaches
``--rel-halfwidth`` (``jaxlc.evaluation.validation``). Writes ``RUN_DIR/validate/``:
``validate.json`` and ``validate.csv`` (per model and failure kind: the probability per lane
change, its 95% interval, relative half-width, effective sample size, lane changes, wall time,
the matmul peak) and ``cases.json`` (every failure up to a cap, highest weight first, with the
key and proposal that replay it); ``report.md`` gains its section. Ctrl-C keeps what was
estimated so far. ``--method ams`` (``jaxlc.evaluation.ams``): P(margin <= m) by adaptive
multilevel splitting, ``ams.json``, its curve and the nearest misses' scenes. A bad argument
is one line and exit 2.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path
from typing import Any

from jaxlc import config
from jaxlc.evaluation import ams, heldout, mixture, proposal, validation
from jaxlc.evaluation import validation_io as io
from jaxlc.evaluation.protocol import final_checkpoints, load_rows
from jaxlc.evaluation.results import SCRIPTED, EvalError
from jaxlc.paper.grid import tag_of
from jaxlc.report import plots, plots_scenes, report, report_heldout
from jaxlc.study import machine
from jaxlc.study.checkpoint import CheckpointError
from jaxlc.study.rundir import RunDir


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.validate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("run_dir", type=Path, help="run directory of jaxlc.sweep")
    ap.add_argument("--model", default="④", help="index, label, tag (④), all or scripted")
    ap.add_argument("--method", choices=("mc", "is", "ams"), default="is")
    ap.add_argument("--lane-changes", type=int, default=1_000_000, help="most per model")
    ap.add_argument("--rel-halfwidth", type=float, default=0.0, help="stop at this (0: never)")
    ap.add_argument("--kind", choices=validation.KINDS, default="collision")
    ap.add_argument(
        "--tilt-from",
        dest="window",
        choices=tuple(proposal.WINDOWS),
        default="acceptance",
        help="is: tilt braking from the gap's acceptance (unbiased) or from the ego's entry "
        "(a ratio estimate)",
    )
    ap.add_argument(
        "--family",
        choices=tuple(mixture.DEFENSIVE_SHARE),
        default="single",
        help="is: one proposal fitted by cross-entropy, or a mixture of one-role braking "
        "tilts, each drawing its role's first braking event within a horizon, the horizons "
        "and shares from pilot rounds (jaxlc.evaluation.mixture)",
    )
    ap.add_argument(
        "--defensive",
        type=float,
        default=None,
        help="is: the share of the estimate's chunks drawn from the traffic's own distribution "
        "(a defensive mixture: every weight at most 1 / share; 0: none); default by "
        f"--family, {mixture.DEFENSIVE_SHARE}",
    )
    ap.add_argument("--traffic", nargs="+", default=[], metavar="env.KEY=VALUE")
    ap.add_argument("--chunk", type=int, default=2048, help="lane-change cases per program")
    ap.add_argument("--chain", type=int, default=1, help="mc: lane changes per case, one traffic")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-steps", type=int, default=config.EvalConfig().max_steps)
    ap.add_argument("--out", type=Path, default=None, help="default: RUN_DIR/validate")
    ap.add_argument("--replay", type=int, default=None, metavar="CASE", help="cases.json index"
                    " (--method ams: ams.json's nearest miss)")  # fmt: skip
    # --method ams (jaxlc.evaluation.ams): P(margin <= --margin) by adaptive multilevel splitting
    ap.add_argument("--particles", type=int, default=1000, help="ams: cases per run")
    ap.add_argument("--kill", type=float, default=0.1, help="ams: share killed per round")
    ap.add_argument("--repeats", type=int, default=10, help="ams: independent runs (interval)")
    ap.add_argument("--margin", type=float, default=0.0, help="ams: the margin m (0: failure)")
    ap.add_argument("--span", type=float, default=None, help="ams: the curve's, above m"
                    " (default: by --kind, ams.cap_of)")  # fmt: skip
    ap.add_argument("--max-rounds", type=int, default=2000, help="ams: 0 is crude MC")
    ap.add_argument("--noise", type=float, default=0.0, help="ams: exploration sigma on actions")
    args = ap.parse_intermixed_args(argv)
    for name in ("lane_changes", "chunk", "max_steps", "chain"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if not 0.0 <= args.rel_halfwidth < 1.0:
        ap.error("--rel-halfwidth must be in [0, 1)")
    if args.defensive is None:
        args.defensive = mixture.DEFENSIVE_SHARE[args.family]
    if not 0.0 <= args.defensive < 1.0:
        ap.error("--defensive must be in [0, 1)")
    return args


def model_rows(run_dir: Path, which: str) -> tuple[config.Config, list[tuple[Any, int, dict]]]:
    """The run's config and the policies ``which`` names (``(actor, k, meta)``): a model
    index, a label, a paper tag (every seed's), ``all`` or ``scripted``."""
    if not RunDir(run_dir).is_run():
        raise EvalError(f"{run_dir} has no config.toml, so it is not a run directory")
    chosen = final_checkpoints(run_dir)
    if which != "scripted":
        tags = ("all",)
        chosen = [
            (p, m)
            for p, m in chosen
            if which in (*tags, str(m.get("model")), str(m.get("label")), tag_of(m))
        ]
        if not chosen:
            raise EvalError(f"--model {which}: no final checkpoint of {run_dir} matches it")
    cfg, actors, metas = load_rows(run_dir, chosen)
    if which == "scripted":
        return cfg, [(None, 1, dict(SCRIPTED))]
    return cfg, [(a, int(m.k or 1), m.as_dict()) for a, m in zip(actors, metas[1:], strict=True)]


def _report(args: argparse.Namespace) -> None:
    """The run's report gains the section (where the run has one and --out is its own)."""
    if args.out is None and RunDir(args.run_dir).eval_json.is_file():
        report.write_report(args.run_dir)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        if args.replay is not None:
            replay = plots_scenes.replay_miss if args.method == "ams" else plots_scenes.replay_case
            path, same = replay(args.run_dir, args.replay, args.out)
            print(f"Wrote {path}; the replay {'matches' if same else 'DIFFERS from'} the case")
            return 0 if same else 1
        if args.method == "ams":
            ams.check(args)
        elif args.noise != 0.0:
            raise EvalError(f"--noise {args.noise:g}: only --method ams adds noise to the actions")
        cfg, rows = model_rows(args.run_dir, args.model)
        cfg = heldout.in_traffic(cfg, args.traffic)
        if args.method == "ams":  # all of it in jaxlc.evaluation.ams
            out = io.validate_dir(args.run_dir, args.out)
            results = io.ams_command(cfg, rows, args, out, machine.matmul_peak_gflops())
            plots.ams_curve(results, out / "ams_curve.png")
            print(f"Wrote {plots_scenes.ams_misses(args.run_dir, out)}")
            _report(args)
            return 0
        names = [f.name for f in dataclasses.fields(validation.Settings)]
        settings = validation.check(
            cfg, validation.Settings(**{n: getattr(args, n) for n in names})
        )
        peak = machine.matmul_peak_gflops()
        results = []
        for i, row in enumerate(rows):
            results.append(validation.estimate(cfg, *row, settings, model=i))
            if results[-1].interrupted:
                break
        out = io.write_outputs(args, cfg, results, peak)
        section = report_heldout.validation_section(args.run_dir, out)
        (out / "validate.md").write_text("\n".join(section) + "\n")
        plots_scenes.validation_scenes(args.run_dir, out, cfg)
        _report(args)
        for r in results:
            e = r.estimates.get(args.kind)
            print(
                f"{r.meta['label']}: {args.kind} {e.estimate if e else math.nan:.3g} "
                f"[{e.lo if e else math.nan:.3g}, {e.hi if e else math.nan:.3g}] per lane "
                f"change, {r.lane_changes} lane changes, {r.wall_s} s"
            )
        print(f"Wrote {out}")
        return 130 if results and results[-1].interrupted else 0
    except (EvalError, CheckpointError, config.ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
