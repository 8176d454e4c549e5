"""``python -m jaxlc.sweep``: train the grid of models (default: the paper's nine) in one process.

    python -m jaxlc.sweep                                  # configs/paper.toml
    python -m jaxlc.sweep --config configs/smoke.toml --out runs/smoke
    python -m jaxlc.sweep train.envs_per_model=64 grid.k=[1,2] --seeds 3

The scan runs in chunks of ``train.chunk_steps``; between chunks the host saves checkpoints
(the actor of every model at episodes checkpoint_every, 2*checkpoint_every, ...), and at the
end the per-episode metrics, the loss curves, a summary table and the resolved config, all
under the run directory:

    RUN_DIR/config.toml                    resolved config (what ran)
    RUN_DIR/checkpoints/mXX_sY/epNNNNN.*   actor params (msgpack) + metadata (json)
    RUN_DIR/metrics/episodes.npz           per model: return, steps, reason, reward terms
    RUN_DIR/metrics/steps.npz              per scan step and model: losses, transitions
    RUN_DIR/summary.md, summary.json       last-100-episode success rate and return
"""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
from pathlib import Path
from typing import Any

import jax
import numpy as np

from jaxlc import checkpoint, config, train
from jaxlc.reward import REASONS, SUCCESS

# The paper's Table 1 numbers the models by (k, memory size).
PAPER_LABELS = {
    (1, 2000): "①",
    (2, 2000): "②",
    (4, 2000): "③",
    (1, 4000): "④",
    (1, 8000): "⑤",
    (2, 4000): "⑥",
    (2, 8000): "⑦",
    (4, 4000): "⑧",
    (4, 8000): "⑨",
}


def model_label(cell: dict[str, Any]) -> str:
    """``"④ k=1 D=4000"``-style name of a grid cell (the circled number only for the paper's
    nine, with the paper's learning rates and noise)."""
    base = f"k={cell['k']} D={cell['memory']}"
    tag = PAPER_LABELS.get((cell["k"], cell["memory"]))
    extra = [
        f"{n}={cell[n]:g}"
        for n in ("actor_lr", "critic_lr", "noise_sigma")
        if cell[n] != getattr(config.DDPGConfig(), n)
    ]
    return " ".join(([tag] if tag and not extra else []) + [base] + extra)


def model_meta(cfg: config.Config, grid: train.Grid, i: int) -> dict[str, Any]:
    cell = grid.cells[grid.cell_of[i]]
    return {
        "model": i,
        "cell": grid.cell_of[i],
        "seed": grid.seeds[i],
        "label": model_label(cell),
        **cell,
        "config_hash": cfg.hash(),
    }


def checkpoint_path(run_dir: Path, i: int, seed: int, episode: int) -> Path:
    return run_dir / "checkpoints" / f"m{i:02d}_s{seed}" / f"ep{episode:05d}.msgpack"


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    checkpoint.write_bytes_atomic(path, buf.getvalue())


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


def summary_markdown(
    rows: list[dict[str, Any]], wall_s: float, env_steps: int, last: int = 100
) -> str:
    lines = [
        f"Wall time {wall_s:.0f} s, {env_steps:,} env-steps ({env_steps / wall_s:,.0f}/s), "
        f"{sum(r['episodes'] for r in rows):,} episodes "
        f"({sum(r['episodes'] for r in rows) / wall_s:.1f}/s).",
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


def prepare_run_dir(out: Path, cfg: config.Config, force: bool) -> None:
    """Create ``out`` for ``cfg``; refuse a directory that already holds another run."""
    existing = out / "config.toml"
    if existing.exists():
        try:
            old = config.load(existing)
        except config.ConfigError:
            old = None
        if old is None or old.hash() != cfg.hash():
            if not force:
                raise config.ConfigError(
                    f"run directory '{out}' already holds a run of another config; "
                    "choose another --out, or pass --force to overwrite it"
                )
        elif not force and (out / "summary.json").exists():
            raise config.ConfigError(
                f"run directory '{out}' already holds a finished run of this config; "
                "choose another --out, or pass --force to train again"
            )
    out.mkdir(parents=True, exist_ok=True)
    checkpoint.write_text_atomic(existing, config.to_toml(cfg))


def run_sweep(
    cfg: config.Config, out: Path, force: bool = False, progress: bool = True
) -> dict[str, Any]:
    """Train every model of ``cfg``'s grid and write the run directory; returns the summary."""
    from tqdm import tqdm

    prepare_run_dir(out, cfg, force)
    grid = train.make_grid(cfg)
    init, run = train.make_grid_fns(cfg, grid)
    t = cfg.train
    t0 = time.perf_counter()
    state = init(train.model_keys(cfg, grid))
    saved = np.zeros(grid.size, np.int64)  # last checkpoint episode written, per model
    step_metrics: list[dict[str, np.ndarray]] = []
    bar = tqdm(
        total=grid.size * t.episodes,
        unit="ep",
        disable=not progress,
        desc=f"{grid.size} models",
        dynamic_ncols=True,
    )
    done_eps, env_steps = 0, 0
    while True:
        t_chunk = time.perf_counter()
        state, metrics = run(state, t.chunk_steps)
        metrics = jax.device_get(metrics)
        step_metrics.append(metrics)
        episodes = np.asarray(state.episodes)
        env_steps += t.chunk_steps * t.envs_per_model * grid.size

        # Checkpoints: the snapshot slot holds the actor at the last checkpoint episode passed.
        snap_ep = np.asarray(state.snap_episode)
        new = np.nonzero(snap_ep > saved)[0]
        if len(new):
            actors = jax.device_get(state.snap_actor)
            for i in new:
                params = jax.tree.map(lambda a, i=i: a[i], actors)
                meta = {**model_meta(cfg, grid, int(i)), "episode": int(snap_ep[i])}
                checkpoint.save(
                    checkpoint_path(out, int(i), grid.seeds[i], int(snap_ep[i])), params, meta
                )
            saved[new] = snap_ep[new]

        now = int(np.minimum(episodes, t.episodes).sum())
        recent = metrics["successes"].sum() / max(1, metrics["episodes_ended"].sum())
        bar.set_postfix(
            success=f"{recent:.0%}",
            steps_s=f"{t.chunk_steps * t.envs_per_model * grid.size / (time.perf_counter() - t_chunk):,.0f}",
        )
        bar.update(now - done_eps)
        done_eps = now
        step = int(np.asarray(state.step)[0])
        if (episodes >= t.episodes).all() or (t.max_steps and step >= t.max_steps):
            break
    bar.close()
    wall = time.perf_counter() - t0

    log = {k: np.asarray(v) for k, v in jax.device_get(state.log).__dict__.items()}
    episodes = np.asarray(state.episodes)
    steps_npz = {k: np.concatenate([m[k] for m in step_metrics]) for k in step_metrics[0]}
    _save_npz(out / "metrics" / "episodes.npz", {**log, "episodes": episodes})
    _save_npz(out / "metrics" / "steps.npz", steps_npz)
    rows = summarise(cfg, grid, log, episodes)
    summary = {
        "wall_s": wall,
        "env_steps": env_steps,
        "models": rows,
        "config_hash": cfg.hash(),
        "device": jax.devices()[0].device_kind,
    }
    checkpoint.write_text_atomic(out / "summary.md", summary_markdown(rows, wall, env_steps))
    checkpoint.write_text_atomic(out / "summary.json", json.dumps(summary, indent=1))
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("overrides", nargs="*", help="table.key=value, e.g. train.episodes=500")
    ap.add_argument("--config", type=Path, default=None, help="TOML file (default: paper)")
    ap.add_argument("--out", type=Path, default=None, help="run directory (default: runs/…)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per grid cell")
    ap.add_argument("--force", action="store_true", help="overwrite a run directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    args = ap.parse_args(argv)
    try:
        overrides = list(args.overrides)
        if args.seeds is not None:
            overrides.append(f"train.seeds={args.seeds}")
        cfg = config.load(args.config, overrides)
        out = args.out or Path("runs") / f"{time.strftime('%Y%m%d-%H%M%S')}-{cfg.hash()}"
        summary = run_sweep(cfg, out, force=args.force, progress=not args.no_progress)
    except (config.ConfigError, checkpoint.CheckpointError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(summary_markdown(summary["models"], summary["wall_s"], summary["env_steps"]))
    print(
        f"Run directory: {out}\n  config:      {out / 'config.toml'}\n"
        f"  checkpoints: {out / 'checkpoints'}\n  metrics:     {out / 'metrics'}\n"
        f"  summary:     {out / 'summary.md'}\n"
        f"Evaluate with: python -m jaxlc.evaluate {out}"
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
