"""Time to solution: wall time from start until the study first has a model at ``--target``
success over its last 100 training episodes (exploration noise on), with this machine's
float32 matmul peak printed beside it, since machines here differ about 2x.

The clock starts before anything is compiled and runs the sweep's own program
(``train.make_grid_fns``, the host-device layout ``python -m jaxlc.sweep`` would pick) chunk
by chunk; after each chunk every model's last-100 success is read from its episode log (the
same figure as the sweep's summary). It stops at the first model to reach the target, or at
``--max-minutes``, or when every model has done its episodes.

    python -m benchmarks.time_to_solution                    # the default study, target 99%
    python -m benchmarks.time_to_solution --seeds 3 --max-minutes 30
    python -m benchmarks.time_to_solution --tiny             # seconds, for tests
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Sequence
from datetime import date
from pathlib import Path


def main(argv: Sequence[str] | None = None) -> dict[str, object]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--config", type=Path, default=None, help="TOML (default: paper)")
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--target", type=float, default=0.99, help="last-100 success to reach")
    ap.add_argument("--last", type=int, default=100, help="episodes the success is over")
    ap.add_argument("--max-minutes", type=float, default=60.0)
    ap.add_argument("--csv", type=Path, default=None)
    ap.add_argument("--tiny", action="store_true", help="smoke config, low target (tests)")
    ap.add_argument("overrides", nargs="*", help="table.key=value, as for the sweep")
    args = ap.parse_args(argv)
    t0 = time.perf_counter()  # the user's clock: compile time counts

    import jax  # its backends start below, after the host devices are asked for
    import numpy as np

    from benchmarks import RESULTS, write_csv
    from jaxlc import config
    from jaxlc.learn import train
    from jaxlc.study import machine
    from jaxlc.study.loop import host_devices
    from jaxlc.study.summary import summarise

    path = config.CONFIG_DIR / "smoke.toml" if args.tiny and args.config is None else args.config
    cfg = config.load(path, [*args.overrides, f"train.seeds={args.seeds}"])
    if args.tiny:
        args.target, args.last = 0.0, 1  # any finished episode: the loop and the log, not RL
    machine.use_host_devices(host_devices(cfg))
    grid = train.make_grid(cfg)
    init, run = train.make_grid_fns(cfg, grid)
    state = init(train.model_keys(grid))
    t = cfg.train
    env_steps, found = 0, None
    while time.perf_counter() - t0 < 60 * args.max_minutes:
        state, _ = run(state, t.chunk_steps)
        env_steps += t.chunk_steps * t.envs_per_model * grid.size
        host = jax.device_get({"episodes": state.episodes, "log": state.log})
        log = {k: np.asarray(v) for k, v in host["log"].columns().items()}
        rows = summarise(cfg, grid, log, host["episodes"], last=args.last)
        ready = [r for r in rows if r["episodes"] >= args.last]
        best = max(ready, key=lambda r: r["success_rate_last"], default=None)
        if best is not None and best["success_rate_last"] >= args.target:
            found = best
            break
        if (host["episodes"] >= t.episodes).all():
            break
    wall = time.perf_counter() - t0
    peak = machine.matmul_peak_gflops()
    row = {
        "date": str(date.today()),
        "processor": platform.processor() or platform.machine(),
        "device": jax.devices()[0].device_kind,
        "devices": len(jax.devices()),
        "matmul_peak_gflops": round(peak, 1),
        "models": grid.size,
        "target": args.target,
        "reached": found is not None,
        "wall_s": round(wall, 1),
        "env_steps": env_steps,
        "model": found["label"] if found else "",
        "seed": found["seed"] if found else "",
        "episode": found["episodes"] if found else "",
        "success_last": round(found["success_rate_last"], 3) if found else "",
    }
    what = (
        f"{row['model']} (seed {row['seed']}) reached {row['success_last']:.0%} over its last "
        f"{args.last} episodes at episode {row['episode']}"
        if found
        else f"no model reached {args.target:.0%} within the budget"
    )
    print(
        f"time to solution: {wall:.1f} s | {what} | {grid.size} models on {row['devices']} "
        f"{row['device']} device(s), {env_steps:,} env-steps | float32 matmul peak "
        f"{peak:.0f} GFLOP/s | jax {jax.__version__} | {row['date']}"
    )
    write_csv(args.csv or RESULTS / "time_to_solution.csv", [row])
    return row


if __name__ == "__main__":
    main()
