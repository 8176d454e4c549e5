"""Several runs of one grid, each over its own seeds, as one run directory.

    python -m jaxlc.sweep train.seed=0 --out runs/seed0      # ... one run per seed
    python -m jaxlc.sweep train.seed=9 --out runs/seed9
    python -m jaxlc.study.merge runs/s10 runs/seed0 ... runs/seed9
    python -m jaxlc.evaluate runs/s10

A seed names its model (``jaxlc.learn.train.make_grid``: ``fold_in(PRNGKey(0), seed)``), so the
model of seed 3 is the same whether its run trained seeds 3..3 or 0..9 (why one run per seed
on a CPU: docs/decisions.md, "one run per seed, merged").

The merged directory is what ``python -m jaxlc.sweep --seeds N`` would have written, in its
model order (cell outermost, then seed): ``config.toml`` with ``train.seed`` the first seed and
``train.seeds`` their count, every checkpoint under its model index in that order (its JSON's
``model`` rewritten, ``merged_from`` added), ``metrics/episodes.npz`` stacked in that order,
``summary.json`` (the runs' wall times and env-steps added, ``merged_from`` listing each run's
directory, seeds and matmul peak) and ``summary.md``. ``metrics/steps.npz`` (per scan step) is
not merged: runs take different step counts; the loss figure is then skipped. The runs must
agree on every config value but ``train.seed`` and ``train.seeds``, and their seeds must not
overlap or leave a gap; else ``MergeError`` names what differs.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import shutil
import sys
from pathlib import Path
from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.study.rundir import RunDir
from jaxlc.study.summary import summary_markdown


class MergeError(ValueError):
    """Runs that cannot be one study; the message says why."""


def _seedless(cfg: config.Config) -> config.Config:
    return dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, seed=0, seeds=1))


def merged_config(runs: list[RunDir]) -> config.Config:
    """The config of the merged study; refuses runs that differ in anything but their seeds."""
    cfgs = [r.load_config() for r in runs]
    first = _seedless(cfgs[0])
    for r, c in zip(runs, cfgs, strict=True):
        if _seedless(c) != first:
            diff = [
                f"{t}.{k}"
                for t, values in _seedless(c).to_dict().items()
                for k, v in values.items()
                if first.to_dict()[t][k] != v
            ]
            raise MergeError(f"{r.root} differs from {runs[0].root} in {', '.join(diff)}")
    seeds = sorted(s for c in cfgs for s in range(c.train.seed, c.train.seed + c.train.seeds))
    if seeds != list(range(seeds[0], seeds[0] + len(seeds))):
        raise MergeError(f"the runs' seeds must be distinct and without gaps, got {seeds}")
    return dataclasses.replace(
        cfgs[0], train=dataclasses.replace(cfgs[0].train, seed=seeds[0], seeds=len(seeds))
    )


def _sources(runs: list[RunDir]) -> dict[tuple[int, int], tuple[RunDir, dict[str, Any]]]:
    """``(cell, seed) -> (run, its summary row)`` over every run."""
    out = {}
    for r in runs:
        if not r.summary_json.is_file():
            raise MergeError(f"{r.root} has no summary.json: finish it first (--resume)")
        for m in r.read_json(r.summary_json)["models"]:
            out[m["cell"], m["seed"]] = (r, m)
    return out


def merge(out: Path, run_dirs: list[Path]) -> dict[str, Any]:
    """Write the merged run directory ``out`` (module docstring); returns its summary."""
    runs = [RunDir(p) for p in run_dirs]
    if not runs:
        raise MergeError("name at least one run directory to merge")
    cfg = merged_config(runs)
    source = _sources(runs)
    order = sorted(source, key=lambda cs: (cs[0], cs[1]))  # the sweep's: cell, then seed
    dst = RunDir(out)
    if dst.root.exists():
        raise MergeError(f"{out} exists; merge into a new directory")
    dst.checkpoints.mkdir(parents=True)
    dst.write_config(cfg)
    logs = {r.root: r.load_npz(r.episodes) for r in runs}
    rows, stacked = [], {}
    for j, (cell, seed) in enumerate(order):
        run, row = source[cell, seed]
        rows.append({**row, "model": j})
        for path in sorted(run.checkpoints.glob(f"m{row['model']:02d}_s{seed}/*.msgpack")):
            target = dst.checkpoint(j, seed, 0).parent / path.name
            target.parent.mkdir(exist_ok=True)
            shutil.copyfile(path, target)
            meta = json.loads(path.with_suffix(".json").read_text())
            meta |= {"model": j, "merged_from": str(run.root)}
            dst.write_text(target.with_suffix(".json"), json.dumps(meta, indent=1))
        for k, v in logs[run.root].items():
            stacked.setdefault(k, []).append(v[row["model"]])
    dst.save_npz(dst.episodes, {k: np.stack(v) for k, v in stacked.items()})
    summaries = [r.read_json(r.summary_json) for r in runs]
    summary = {
        **summaries[0],
        "wall_s": sum(s["wall_s"] for s in summaries),
        "env_steps": sum(s["env_steps"] for s in summaries),
        "models": rows,
        "config_hash": cfg.hash(),
        "matmul_peak_gflops": float(np.mean([s["matmul_peak_gflops"] for s in summaries])),
        "merged_from": [
            {
                "run": str(r.root),
                "seeds": sorted({m["seed"] for m in s["models"]}),
                "wall_s": s["wall_s"],
                "matmul_peak_gflops": s["matmul_peak_gflops"],
            }
            for r, s in zip(runs, summaries, strict=True)
        ],
    }
    dst.write_text(dst.summary_md, summary_markdown(summary))
    dst.write_text(dst.summary_json, json.dumps(summary, indent=1))
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.study.merge", description=__doc__.splitlines()[0]
    )
    ap.add_argument("out", type=Path, help="the merged run directory (must not exist)")
    ap.add_argument("runs", type=Path, nargs="+", help="finished run directories")
    args = ap.parse_args(argv)
    try:
        summary = merge(args.out, args.runs)
    except (MergeError, config.ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"Wrote {args.out}: {len(summary['models'])} models from {len(args.runs)} runs")
    return 0


if __name__ == "__main__":
    sys.exit(main())
