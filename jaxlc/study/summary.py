"""A run's models by name and how their last episodes went: each model's label and metadata
(what its checkpoints and ``summary.json`` carry), the summary rows, and ``summary.md`` with
the run's speed on the machine that gave it (written by the sweep and by
``jaxlc.study.merge``)."""

from __future__ import annotations

from typing import Any

import numpy as np

from jaxlc import config
from jaxlc.learn import train
from jaxlc.paper import grid as grid_of_paper
from jaxlc.sim.reward import REASONS, SUCCESS


def model_label(cell: dict[str, Any]) -> str:
    """``"④ k=1 D=4000"``-style name of a grid cell (the circled number only for the paper's
    nine, with the paper's learning rates and noise: ``paper.grid.tag_of``)."""
    base = f"k={cell['k']} D={cell['memory']}"
    tag = grid_of_paper.tag_of(cell)
    extra = [
        f"{n}={cell[n]:g}"
        for n in ("actor_lr", "critic_lr", "noise_sigma")
        if cell[n] != getattr(config.DDPGConfig(), n)
    ]
    return " ".join(([tag] if tag else []) + [base] + extra)


def model_meta(cfg: config.Config, grid: train.Grid, i: int) -> dict[str, Any]:
    cell = grid.cells[grid.cell_of[i]]
    return {
        "model": i,
        "cell": grid.cell_of[i],
        "seed": grid.seeds[i],
        "label": model_label(cell),
        **cell,
        "hidden": list(cfg.ddpg.hidden),  # the network: jaxlc.policy.load_policy
        "symmetric_actor": cfg.ddpg.symmetric_actor,
        "config_hash": cfg.hash(),
    }


def summarise(
    cfg: config.Config,
    grid: train.Grid,
    log: dict[str, np.ndarray],
    episodes: np.ndarray,
    last: int = 100,
) -> list[dict[str, Any]]:
    rows = []
    for i in range(grid.size):
        n = int(min(episodes[i], cfg.train.episodes))
        lo = max(0, n - last)
        reason, ret = log["reason"][i, lo:n], log["ret"][i, lo:n]
        rows.append(
            {
                **model_meta(cfg, grid, i),
                "episodes": n,
                "success_rate_last": float((reason == SUCCESS).mean()) if n else float("nan"),
                "return_last": float(ret.mean()) if n else float("nan"),
                "steps_last": float(log["steps"][i, lo:n].mean()) if n else float("nan"),
                "ends_last": {REASONS[r]: int((reason == r).sum()) for r in range(1, 5)},
            }
        )
    return rows


def summary_markdown(summary: dict[str, Any], last: int = 100) -> str:
    """The summary as markdown: one line of speed, with the machine that gave it, and a table."""
    rows, wall_s, env_steps = summary["models"], summary["wall_s"], summary["env_steps"]
    lines = [
        f"Wall time {wall_s:.0f} s, {env_steps:,} env-steps ({env_steps / wall_s:,.0f}/s), "
        f"{sum(r['episodes'] for r in rows):,} episodes "
        f"({sum(r['episodes'] for r in rows) / wall_s:.1f}/s), on {summary['devices']} "
        f"{summary['device']} device(s); float32 matmul peak of this machine "
        f"{summary['matmul_peak_gflops']:.0f} GFLOP/s.",
        "",
        f"| model | seed | episodes | success (last {last}) | return (last {last}) | "
        f"manoeuvre steps | out of bounds / collision / timeout |",
        "|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        e = r["ends_last"]
        lines.append(
            f"| {r['label']} | {r['seed']} | {r['episodes']} | {r['success_rate_last']:.1%} | "
            f"{r['return_last']:.1f} | {r['steps_last']:.1f} | "
            f"{e['out_of_bounds']} / {e['collision']} / {e['timeout']} |"
        )
    return "\n".join(lines) + "\n"
