"""Training throughput with the models axis laid over 1, 2, ... devices (``--devices``).

For each device count N, ``train.make_grid_fns(cfg, grid, jax.devices()[:N])`` builds the
sweep's own program (the simulator and the DDPG update in one ``lax.scan``, models over a
1-D mesh with ``shard_map``); one chunk of ``--steps`` scan steps compiles it, then the median
of ``--repeats`` timed chunks gives grid-updates/s (a scan step makes one DDPG update in every
model) and env-steps/s (every env of every model steps once per scan step).

On a CPU the devices are host devices that XLA makes with
``--xla_force_host_platform_device_count`` (set here before JAX starts, from the largest
count asked for); they share the machine's cores. On a GPU machine ``jax.devices()`` are the
GPUs, and ``--devices`` cannot exceed their number.

    python -m benchmarks.devices_throughput                      # paper grid, N = 1 2 3
    python -m benchmarks.devices_throughput --devices 1 --tiny   # seconds, for tests
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Sequence
from datetime import date
from pathlib import Path

import jax

from benchmarks import RESULTS, write_csv
from jaxlc import config
from jaxlc.learn import train
from jaxlc.study import machine


def main(argv: Sequence[str] | None = None) -> list[dict[str, object]]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--devices", type=int, nargs="+", default=[1, 2, 3])
    ap.add_argument("--config", type=Path, default=None, help="TOML (default: paper)")
    ap.add_argument("--steps", type=int, default=150, help="scan steps per timed chunk")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--csv", type=Path, default=None)
    ap.add_argument("--tiny", action="store_true", help="smoke config, few steps (tests)")
    args = ap.parse_args(argv)
    machine.use_host_devices(max(args.devices))  # before JAX starts its backends
    cfg = config.load(
        config.CONFIG_DIR / "smoke.toml" if args.tiny and args.config is None else args.config
    )
    steps, repeats = (20, 2) if args.tiny else (args.steps, args.repeats)
    grid = train.make_grid(cfg)
    if max(args.devices) > len(jax.devices()):
        raise SystemExit(f"--devices: JAX sees {len(jax.devices())} devices: {jax.devices()}")
    print(
        f"jaxlc training throughput by device count | {platform.processor() or platform.machine()}"
        f" | {jax.devices()[0].device_kind} | {os.cpu_count()} cores | jax {jax.__version__} | "
        f"{grid.size} models x {cfg.train.envs_per_model} envs | {date.today()}"
    )
    print(f"{'devices':>7} {'grid-updates/s':>15} {'env-steps/s':>12} {'first chunk s':>14}")
    rows = []
    for n in args.devices:
        init, run = train.make_grid_fns(cfg, grid, jax.devices()[:n])
        state = init(train.model_keys(grid))
        t0 = time.perf_counter()
        state, _ = jax.block_until_ready(run(state, steps))
        first = time.perf_counter() - t0
        times = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            state, _ = jax.block_until_ready(run(state, steps))
            times.append(time.perf_counter() - t0)
        rate = steps / statistics.median(times)
        row = {
            "devices": n,
            "device_kind": jax.devices()[0].device_kind,
            "models": grid.size,
            "envs_per_model": cfg.train.envs_per_model,
            "steps": steps,
            "grid_updates_per_s": round(rate, 2),
            "env_steps_per_s": round(rate * grid.size * cfg.train.envs_per_model),
            "first_chunk_s": round(first, 2),
        }
        rows.append(row)
        print(
            f"{n:>7} {row['grid_updates_per_s']:>15,.1f} {row['env_steps_per_s']:>12,} "
            f"{first:>14.1f}",
            flush=True,
        )
    write_csv(args.csv or RESULTS / "devices_throughput.csv", rows)
    return rows


if __name__ == "__main__":
    main()
