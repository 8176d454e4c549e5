"""``python -m jaxlc.evaluate RUN_DIR``: run saved checkpoints on fixed lane-change cases.

    python -m jaxlc.evaluate runs/smoke                        # default checkpoints, 100 cases
    python -m jaxlc.evaluate runs/paper --episodes 100,5000 --model 3
    python -m jaxlc.evaluate --checkpoint runs/paper/checkpoints/m03_s0/ep05000.msgpack
    python -m jaxlc.evaluate runs/smoke --heldout-only --traffic env.mobil=true env.braking=true
    python -m jaxlc.evaluate runs/smoke --suite      # every setting of configs/suite.toml
    python -m jaxlc.evaluate runs/any_road --choose --suite   # each model's checkpoint chosen

The cases are ``jaxlc.evaluation.cases``, a result row ``jaxlc.evaluation.results``; this
module picks the checkpoints, runs them and writes the files (outcomes: the reason codes of
``jaxlc.sim.reward``, 0 read as "unfinished", hit the step cap). Writes
``RUN_DIR/eval/eval.json``, ``eval.csv``, ``cases.npz``, ``traces.npz``, the statistics over
seeds (``jaxlc.evaluation.stats``), then the figures and ``RUN_DIR/report.md``.

Beside the paper's 100 cases, each model's final checkpoint (and those of
``--heldout-episodes``) drives ``--lane-changes`` held-out lane changes (``--heldout-seed``):
failure rates with binomial intervals, the safety and comfort norms, every collision
attributed (``jaxlc.evaluation.heldout``), into ``eval/heldout.json``, ``heldout*.csv``,
``collisions.csv``, ``heldout_cases.npz``; with ``--traffic env.KEY=VALUE ...`` (or ``[eval]
traffic``) in that traffic instead of the training's, into ``eval/heldout_TAG/``.

    python -m jaxlc.evaluate --compare RUN_A RUN_B [--out DIR]

compares two evaluated runs (their ``eval/eval.json``): per cell and checkpoint, B - A of the
mean success rate with a bootstrap interval, into ``DIR`` (default ``RUN_B/compare_<name of
RUN_A>/``); runs whose cells differ, or that share no checkpoint episode, are refused (exit 2).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax

from jaxlc import config
from jaxlc.evaluation.protocol import (  # the names the command's users and tests know it by
    default_episodes,
    evaluate_checkpoint,
    evaluate_heldout,
    evaluate_run,
    final_checkpoints,
    load_rows,
    select_checkpoints,
    write_convergence,
    write_seed_stats,
)
from jaxlc.evaluation.results import EvalError
from jaxlc.evaluation.stats import StatsError
from jaxlc.report.report_seeds import compare_runs
from jaxlc.report.report_text import format_heldout, format_table
from jaxlc.sim.env import action_dim
from jaxlc.sim.observation import OBS_DIM
from jaxlc.study import machine
from jaxlc.study.checkpoint import CheckpointError
from jaxlc.study.rundir import RunDir

__all__ = ["compare_runs", "default_episodes", "evaluate_checkpoint", "evaluate_heldout"]
__all__ += ["evaluate_run", "final_checkpoints", "load_rows", "main", "select_checkpoints"]
__all__ += ["write_convergence", "write_seed_stats"]


def _episodes_arg(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected episodes like 100,400,800, got {text!r}"
        ) from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one episode")
    return values


def _protocol(args: argparse.Namespace) -> tuple[config.Config, config.EvalConfig]:
    """The run's config (defaults for a lone checkpoint) and its ``[eval]`` protocol with the
    flags given in place of its values (each ``[eval]`` key that is also a flag), checked as
    the config's are."""
    run = RunDir(args.run_dir) if args.run_dir else None
    cfg = run.load_config() if run and run.is_run() else config.Config()
    given = {k: v for k in vars(cfg.eval) if (v := getattr(args, k, None)) is not None}
    return cfg, config.from_dict({"eval": {**vars(cfg.eval), **given}}).eval


def _host_devices(cfg: config.Config, ev: config.EvalConfig) -> int:
    """``machine.host_devices_for`` a chunk of policies, each an actor over every case."""
    widths = (OBS_DIM, *cfg.ddpg.hidden, action_dim(cfg.env))
    return machine.host_devices_for(ev.chunk, machine.largest_product(ev.cases, widths))


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.evaluate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("run_dir", type=Path, nargs="?", help="run directory of jaxlc.sweep")
    ap.add_argument("--episodes", type=_episodes_arg, default=None, help="e.g. 100,400,800")
    ap.add_argument("--cases", type=int, help="lane-change cases (default: eval.cases, 100)")
    ap.add_argument("--model", type=int, default=None, help="evaluate only this model index")
    ap.add_argument("--checkpoint", type=Path, default=None, help="evaluate one .msgpack file")
    ap.add_argument("--seed", type=int, help="seed of the cases (default: eval.seed, 0)")
    ap.add_argument("--max-steps", type=int, help="step cap per case (eval.max_steps)")
    ap.add_argument("--chunk", type=int, help="policies per compiled batch (eval.chunk)")
    ap.add_argument("--no-figures", action="store_true", help="skip figures (report still)")
    ap.add_argument("--lane-changes", type=int, help="held-out lane changes (eval.lane_changes)")
    ap.add_argument("--heldout-seed", type=int, help="seed of the held-out cases")
    ap.add_argument("--traffic", nargs="+", metavar="env.KEY=VALUE", help="eval.traffic")
    ap.add_argument("--tag", default="traffic", help="--traffic: eval/heldout_TAG/")
    ap.add_argument("--heldout-only", action="store_true", help="held-out lane changes only")
    ap.add_argument("--suite", nargs="?", const="", help="the held-out suite (eval.suite) only")
    ap.add_argument("--heldout-episodes", type=_episodes_arg, help="held-out checkpoints too")
    ap.add_argument("--choose", action="store_true", help="each model's checkpoint (eval.choose_*)")
    ap.add_argument(
        "--devices",
        type=int,
        default=None,
        help="devices to lay the policies over (default: every GPU; on a CPU, host devices as "
        "jaxlc/study/machine.py picks for --chunk policies over --cases; XLA_FLAGS overrides it)",
    )
    ap.add_argument(
        "--compare",
        nargs=2,
        type=Path,
        metavar=("RUN_A", "RUN_B"),
        help="compare two evaluated runs cell by cell (B - A); no evaluation",
    )
    ap.add_argument("--out", type=Path, default=None, help="--compare: output directory")
    return ap.parse_intermixed_args(argv)


def _evaluate_run_dir(args: argparse.Namespace, ev: config.EvalConfig, devices: int) -> int:
    """The protocol's cases, the learning-speed measures, the held-out lane changes, the
    figures and the report of ``args.run_dir``."""
    if args.run_dir is None:
        raise EvalError("give a run directory (or --checkpoint FILE)")
    kw = dict(max_steps=ev.max_steps, chunk=ev.chunk, devices=devices)
    held = dict(lane_changes=ev.lane_changes, seed=ev.heldout_seed, **kw)
    if args.choose:  # eval/choice.json: each model's policy in every evaluation after it
        from jaxlc.evaluation.suite import choose

        chosen = (ev.choose_episodes, ev.choose_lane_changes, ev.choose_seed)
        print(choose(args.run_dir, args.suite or ev.suite, *chosen, **kw).table())
        if args.suite is None:
            return 0
    if args.suite is not None:  # jaxlc.evaluation.suite: every named setting, one CSV
        from jaxlc.evaluation import suite
        from jaxlc.report.plots import suite_figure

        rows = suite.run_suite(args.run_dir, args.suite or ev.suite, **held)
        png = suite_figure({args.run_dir.name: rows}, RunDir(args.run_dir).eval / "suite/suite.png")
        print(f"Wrote {png.parent}: {len(rows)} rows")
        return 0
    other_traffic = dict(tag=args.tag, traffic=ev.traffic, **held)  # --traffic, --tag
    if args.heldout_only:
        result = evaluate_heldout(args.run_dir, args.heldout_episodes, **other_traffic)
        print(format_heldout(result.rows))
        return 0
    result = evaluate_run(
        args.run_dir, args.episodes, cases=ev.cases, model=args.model, seed=ev.seed, **kw
    )
    print(format_table(result.rows))
    write_convergence(args.run_dir)
    if ev.lane_changes > 0:
        result = evaluate_heldout(args.run_dir, args.heldout_episodes, **other_traffic)
        print(format_heldout(result.rows))
    from jaxlc.report import plots, report

    made = [] if args.no_figures else plots.make_all(args.run_dir)
    path = report.write_report(args.run_dir)
    print(f"Wrote {RunDir(args.run_dir).eval}, {len(made)} figures, {path}")
    return 0


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        if args.compare is not None:
            out = compare_runs(*args.compare, args.out)
            print(f"Wrote {out / 'compare.md'}, compare.csv, compare.png")
            return 0
        cfg, ev = _protocol(args)
        auto = args.devices is None
        machine.use_host_devices(_host_devices(cfg, ev) if auto else args.devices)
        if args.checkpoint is not None:
            result = evaluate_checkpoint(
                args.checkpoint, args.run_dir, cases=ev.cases, seed=ev.seed, max_steps=ev.max_steps
            )
            print(format_table(result.rows))
            return 0
        return _evaluate_run_dir(args, ev, len(jax.devices()) if auto else args.devices)
    except (EvalError, StatsError, CheckpointError, config.ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
