"""``python -m jaxlc.validate RUN_DIR``: how rarely a policy fails, per lane change.

    python -m jaxlc.validate runs/s3 --model ④ --method is --lane-changes 100000
    python -m jaxlc.validate runs/s3 --model scripted --method mc --rel-halfwidth 0.2 \\
        --traffic env.braking=true
    python -m jaxlc.validate runs/s3 --replay 0        # validate/cases.json's first, a GIF

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
estimated so far. A bad argument is one line and exit 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from tqdm import tqdm

from jaxlc import config
from jaxlc.evaluation import heldout, mixture, proposal, validation
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation.cases import columns
from jaxlc.evaluation.mixture import Mixture
from jaxlc.evaluation.protocol import final_checkpoints, load_rows
from jaxlc.evaluation.results import SCRIPTED, EvalError
from jaxlc.evaluation.validation_io import replay_case, write_outputs
from jaxlc.paper.grid import tag_of
from jaxlc.sim.env import EnvParams
from jaxlc.sim.params import value_range
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
    ap.add_argument("--method", choices=("mc", "is"), default="is")
    ap.add_argument("--lane-changes", type=int, default=1_000_000, help="most per model")
    ap.add_argument("--rel-halfwidth", type=float, default=0.0, help="stop at this (0: never)")
    ap.add_argument("--kind", choices=validation.KINDS, default="collision")
    ap.add_argument(
        "--tilt-from",
        choices=proposal.TILT_FROM,
        default="acceptance",
        help="is: tilt braking from the gap's acceptance (unbiased), from the command on or "
        "from the ego's entry (ratio estimates)",
    )
    ap.add_argument(
        "--family",
        choices=("single", "mixture"),
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
        "(a defensive mixture: every weight at most 1 / share; 0: none); default "
        f"{validation.DEFENSIVE_SHARE}, with --family mixture {mixture.DEFENSIVE_SHARE}",
    )
    ap.add_argument("--traffic", nargs="+", default=[], metavar="env.KEY=VALUE")
    ap.add_argument("--chunk", type=int, default=2048, help="lane-change cases per program")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--max-steps", type=int, default=config.EvalConfig().max_steps)
    ap.add_argument("--out", type=Path, default=None, help="default: RUN_DIR/validate")
    ap.add_argument("--replay", type=int, default=None, metavar="CASE", help="cases.json index")
    args = ap.parse_intermixed_args(argv)
    for name in ("lane_changes", "chunk", "max_steps"):
        if getattr(args, name) < 1:
            ap.error(f"--{name.replace('_', '-')} must be >= 1")
    if not 0.0 <= args.rel_halfwidth < 1.0:
        ap.error("--rel-halfwidth must be in [0, 1)")
    if args.defensive is None:
        mixed = args.family == "mixture"
        args.defensive = mixture.DEFENSIVE_SHARE if mixed else validation.DEFENSIVE_SHARE
    if not 0.0 <= args.defensive < 1.0:
        ap.error("--defensive must be in [0, 1)")
    return args


def model_rows(run_dir: Path, which: str) -> tuple[config.Config, list[dict[str, Any]]]:
    """The run's config and the policies ``which`` names (``{"actor", "k", "meta"}``): a model
    index, a label, a paper tag (every seed's), ``all`` or ``scripted``."""
    if not RunDir(run_dir).is_run():
        raise EvalError(f"{run_dir} has no config.toml, so it is not a run directory")
    chosen = final_checkpoints(run_dir)
    if which != "scripted":
        chosen = [
            (p, m)
            for p, m in chosen
            if which in ("all", str(m.get("model")), str(m.get("label")), tag_of(m))
        ]
        if not chosen:
            raise EvalError(f"--model {which}: no final checkpoint of {run_dir} matches it")
    cfg, actors, metas = load_rows(run_dir, chosen)
    if which == "scripted":
        return cfg, [{"actor": None, "k": 1, "meta": dict(SCRIPTED)}]
    return cfg, [
        {"actor": a, "k": int(m["k"] or 1), "meta": m}
        for a, m in zip(actors, metas[1:], strict=True)
    ]


def fit(
    base: EnvParams, run: Any, pol: Any, args: argparse.Namespace
) -> tuple[proposal.Proposal | Mixture, list[dict]]:
    """The proposal the estimate draws from and the fit's record of each pilot round: the
    nominal (``mc``), the CE's proposal or mixture (``is``)."""
    if args.method == "mc":
        return proposal.nominal(base), []
    if args.family == "mixture":
        start = mixture.start(base, args.defensive, args.tilt_from, args.max_steps)
        return mixture.fit_mixture(
            run, pol, base, start, args.chunk, kind=args.kind, seed=args.seed, log=tqdm.write
        )
    window = float(proposal.TILT_FROM.index(args.tilt_from))
    start = validation.start_proposal(base).replace(tilt_from=window)
    return validation.fit_proposal(
        run, pol, base, start, args.chunk, kind=args.kind, seed=args.seed, log=tqdm.write
    )


def chunk_proposal(
    fitted: proposal.Proposal | Mixture,
    base: EnvParams,
    index: int,
    args: argparse.Namespace,
    components: list[int],
) -> tuple[proposal.Proposal, int, dict[str, Any]]:
    """The estimate's chunk ``index`` (``components``: the mixture's of the chunks before):
    the proposal it draws from, its component (-1: the traffic's own distribution) and what
    its failures record to replay."""
    if isinstance(fitted, Mixture):
        k = fitted.next_component(components)
        q = fitted.component(base, k)
        return q, k, {"proposal": q.to_dict()}
    nominal = args.method == "is" and validation.nominal_chunk(index, args.defensive)
    # the defensive mixture's two components, the flag a float32 array in both: one program
    return fitted.replace(drawn_nominal=jnp.float32(nominal)), -1 if nominal else 0, {}


def estimate(cfg: config.Config, row: dict, args: argparse.Namespace) -> dict:
    """One policy's validation: the proposal (``is``), then chunks until the lane changes or
    the relative half-width are reached, or Ctrl-C."""
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    tilted = args.method == "is"
    run = validation.program(cfg, args.max_steps, tilted)
    pol = validation.policies(cfg, row["actor"], row["k"])
    t0 = time.perf_counter()
    fitted, history = fit(base, run, pol, args)
    mixed = isinstance(fitted, Mixture)
    ratio = tilted and args.tilt_from != "acceptance"
    tally = validation.Tally(ratio=ratio, mixture=fitted if mixed else None)
    lo, interrupted = 0, False
    bar = tqdm(total=args.lane_changes, unit="lc", desc=str(row["meta"]["label"]), leave=False)
    t1 = time.perf_counter()
    try:
        while tally.lane_changes < args.lane_changes:
            keys = streams.stream(args.seed, streams.VALIDATE, range(lo, lo + args.chunk))
            q, k, drawn = chunk_proposal(fitted, base, lo // args.chunk, args, tally.components)
            out = columns(jax.device_get(run(q, pol, keys))[0])
            before = tally.lane_changes
            tally.add(out, lo, np.asarray(keys), base.dt, tilted, k < 0, k, drawn)
            lo += args.chunk
            bar.update(tally.lane_changes - before)
            est = tally.estimates(args.method)[args.kind]
            bar.set_postfix(p=f"{est['estimate']:.3g}", rel=f"{est['rel_halfwidth']:.3g}")
            if est["rel_halfwidth"] <= args.rel_halfwidth:
                break
    except KeyboardInterrupt:
        interrupted = True
    bar.close()
    t2 = time.perf_counter()
    return {
        "meta": row["meta"],
        "method": args.method,
        "proposal": (tally.drawn_mixture if mixed else fitted).to_dict(),
        "defensive": tally.defensive,
        "ce": history,
        "estimates": tally.estimates(args.method),
        "lane_changes": tally.lane_changes,
        "cases_started": tally.started,
        "ce_s": round(t1 - t0, 1),
        "wall_s": round(t2 - t0, 1),
        "lane_changes_per_s": round(tally.lane_changes / max(t2 - t1, 1e-9), 1),
        "interrupted": interrupted,
        "cases": tally.cases,
    }


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        if args.replay is not None:
            path, same = replay_case(args.run_dir, args.replay, args.out)
            print(f"Wrote {path}; the replay {'matches' if same else 'DIFFERS from'} the case")
            return 0 if same else 1
        cfg, rows = model_rows(args.run_dir, args.model)
        cfg = heldout.in_traffic(cfg, args.traffic)
        if (
            args.method == "is"
            and args.family == "mixture"
            and not (cfg.env.braking and value_range(cfg.env.braking_rate)[1] > 0)
        ):
            raise EvalError(
                "--family mixture tilts braking events, and this traffic has none "
                "(--traffic env.braking=true, env.braking_rate > 0)"
            )
        peak = machine.matmul_peak_gflops()
        results = []
        for row in rows:
            results.append(estimate(cfg, row, args))
            if results[-1]["interrupted"]:
                break
        out = write_outputs(args, cfg, results, peak)
        if args.out is None and RunDir(args.run_dir).eval_json.is_file():
            from jaxlc.evaluation import report  # the run's report gains the section

            report.write_report(args.run_dir)
        for r in results:
            e = r["estimates"].get(args.kind, {})
            print(
                f"{r['meta']['label']}: {args.kind} {e.get('estimate', float('nan')):.3g} "
                f"[{e.get('lo', float('nan')):.3g}, {e.get('hi', float('nan')):.3g}] per lane "
                f"change, {r['lane_changes']} lane changes, {r['wall_s']} s"
            )
        print(f"Wrote {out}")
        return 130 if results and results[-1]["interrupted"] else 0
    except (EvalError, CheckpointError, config.ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
