"""A sweep's timing, light: its ``summary.json`` without the per-model rows, plus what the
steady rate after the first chunk needs from its ``config.toml``.

    python -m benchmarks.sweep_timing RUN OUT.json

Writes ``wall_s``, ``first_chunk_s`` (its compilation included), ``env_steps``, the device,
the matmul peak, the number of models and the run's ``train.episodes``, ``chunk_steps`` and
``envs_per_model`` (docs/benchmarks.md's GPU section: ``tables/gpu.py``)."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from jaxlc.study.rundir import RunDir


def main(run: Path, out: Path) -> None:
    rd = RunDir(run)
    summary, train = RunDir.read_json(rd.summary_json), rd.load_config().train
    light = {k: v for k, v in summary.items() if k != "models"}
    light |= {
        "models": len(summary["models"]),
        "episodes_per_model": train.episodes,
        "chunk_steps": train.chunk_steps,
        "envs_per_model": train.envs_per_model,
    }
    RunDir.write_text(out, json.dumps(light, indent=1) + "\n")


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path, help="the sweep's run directory")
    ap.add_argument("out", type=Path, help="the light JSON to write")
    args = ap.parse_args()
    main(args.run, args.out)
