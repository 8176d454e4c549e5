"""``python -m jaxlc.sweep``: train the grid of models (default: the paper's nine) in one process.

    python -m jaxlc.sweep                                  # configs/default.toml
    python -m jaxlc.sweep --config configs/smoke.toml --out runs/smoke
    python -m jaxlc.sweep train.envs_per_model=64 grid.k=[1,2] --seeds 3
    python -m jaxlc.sweep --devices 4                      # models laid over 4 devices
    python -m jaxlc.sweep --distributed ...                # one per host: docs/operations.md

The scan runs in chunks of ``train.chunk_steps``; between chunks the host saves checkpoints
(the actor of every model at episodes checkpoint_every, 2*checkpoint_every, ...), and at the
end the per-episode metrics, the loss curves, a summary table and the resolved config, all
under the run directory:

    RUN_DIR/config.toml                    resolved config (what ran)
    RUN_DIR/checkpoints/mXX_sY/epNNNNN.*   actor params (msgpack) + metadata (json)
    RUN_DIR/metrics/episodes.npz           per model: return, steps, reason, reward terms
    RUN_DIR/metrics/steps.npz              per scan step and model: losses, transitions
    RUN_DIR/summary.md, summary.json       last-100-episode success rate and return

One writer per run directory: the sweep holds an OS lock on ``RUN_DIR/lock`` for its whole
life (``jaxlc.study.lock``), and a second sweep or ``--resume`` there is refused (exit status 2).
SIGINT (Ctrl-C), SIGTERM and SIGUSR1 stop the run at the end of the chunk in flight, save
the full state and exit with 128 + the signal's number (130, 143, 138); ``--resume`` goes on.

Multi-host (``--distributed``): every process runs this same program after
``jax.distributed.initialize``; the models axis spans the devices of all processes. Process 0
alone writes, every file of the run (it has every result gathered anyway), and holds the
lock; the run directory must be on a file system that every host sees, as ``--resume`` reads
it on every process.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

import jax

from jaxlc import config
from jaxlc.study import checkpoint, machine
from jaxlc.study.loop import (  # the names the command's users and tests know it by
    NumericalFault,
    after_write_error,
    host_devices,
    run_sweep,
)
from jaxlc.study.multihost import distributed_init
from jaxlc.study.rundir import RunDir
from jaxlc.study.runstate import take_run_dir
from jaxlc.study.signals import HOLD_ENV, HOLD_LINE, Interrupted
from jaxlc.study.summary import model_label, summarise, summary_markdown

__all__ = ["HOLD_ENV", "HOLD_LINE", "host_devices", "main", "model_label", "run_sweep"]
__all__ += ["summarise", "take_run_dir"]


def parse_args(argv: list[str] | None = None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.sweep",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("overrides", nargs="*", help="table.key=value, e.g. train.episodes=500")
    ap.add_argument(
        "--config", type=Path, default=None, help="TOML file (default: configs/default.toml)"
    )
    ap.add_argument("--out", type=Path, default=None, help="run directory (default: runs/...)")
    ap.add_argument("--seeds", type=int, default=None, help="seeds per grid cell")
    ap.add_argument(
        "--resume",
        type=Path,
        default=None,
        metavar="RUN_DIR",
        help="continue the run saved in RUN_DIR",
    )
    ap.add_argument("--force", action="store_true", help="overwrite a run directory")
    ap.add_argument("--no-progress", action="store_true", help="no progress bar")
    ap.add_argument(
        "--devices",
        type=int,
        default=None,
        help="devices to lay the models over (default: every GPU; on a CPU, the host-device "
        "count that trains fastest, see jaxlc/study/machine.py; XLA_FLAGS overrides it)",
    )
    ap.add_argument(
        "--distributed",
        action="store_true",
        help="multi-host: start jax.distributed from the environment (docs/operations.md); "
        "needs --out or --resume on a shared file system",
    )
    ap.add_argument(
        "--tensorboard",
        type=Path,
        default=None,
        metavar="DIR",
        help="write live curves per model to DIR (tensorboard --logdir DIR); needs tensorboardX",
    )
    return ap.parse_intermixed_args(argv)


def resolve_run(args: argparse.Namespace) -> tuple[config.Config, Path]:
    """The config and run directory the arguments ask for: a resumed run's own, or a new one
    (``--config`` with overrides and ``--seeds``; ``--out`` or a fresh ``runs/...``)."""
    if args.distributed and args.out is None and args.resume is None:
        raise config.ConfigError(
            "--distributed: pass --out DIR (the same on every host), or --resume DIR"
        )
    if args.resume is not None:
        if args.overrides or args.config or args.seeds is not None or args.out:
            raise config.ConfigError(
                "--resume takes the run's own config.toml; drop --config, --out, --seeds "
                "and overrides"
            )
        rd = RunDir(args.resume)
        if not rd.is_run():
            raise config.ConfigError(
                f"'{rd.root}' holds no run (no config.toml); start one with --out"
            )
        return rd.load_config(), rd.root
    overrides = list(args.overrides)
    if args.seeds is not None:
        overrides.append(f"train.seeds={args.seeds}")
    cfg = config.load(args.config, overrides)
    return cfg, args.out or Path("runs") / f"{time.strftime('%Y%m%d-%H%M%S')}-{cfg.hash()}"


def _print_done(summary: dict[str, Any], cfg: config.Config, out: Path) -> None:
    rd = RunDir(out)
    print(summary_markdown(summary))
    print(
        f"Run directory: {out}\n  config:      {rd.config}\n"
        f"  checkpoints: {rd.checkpoints}\n  metrics:     {rd.episodes.parent}\n"
        f"  summary:     {rd.summary_md}"
    )
    if checkpoint.list_checkpoints(out):
        print(f"Evaluate with: python -m jaxlc.evaluate {out}")
    else:
        print(
            f"No checkpoint was saved (the first comes at episode {cfg.train.checkpoint_every}"
            " of a model); train longer before evaluating"
        )


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    out = None
    try:
        cfg, out = resolve_run(args)  # reads files only: JAX is not started yet
        if args.distributed:
            distributed_init()
        if not args.distributed:  # a multi-host run uses the hosts' devices as they are
            machine.use_host_devices(host_devices(cfg) if args.devices is None else args.devices)
        summary = run_sweep(
            cfg,
            out,
            force=args.force,
            progress=not args.no_progress,
            resume=args.resume is not None,
            devices=args.devices,
            tensorboard=args.tensorboard,
        )
    except checkpoint.WriteError as err:
        print(f"error: {after_write_error(err, out)}", file=sys.stderr)
        return 2
    except (config.ConfigError, checkpoint.CheckpointError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except NumericalFault as err:
        print(f"error: {err}", file=sys.stderr)
        return 3
    except Interrupted as err:
        print(
            f"\ninterrupted by {err}: state saved; continue with python -m jaxlc.sweep "
            f"--resume {out}",
            file=sys.stderr,
        )
        return 128 + err.signum  # what a shell reports for a process the signal killed
    except KeyboardInterrupt:  # Ctrl-C before the run's own handler was in place
        print("\ninterrupted before training started: nothing saved", file=sys.stderr)
        return 130
    if jax.process_index() == 0:
        _print_done(summary, cfg, out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
