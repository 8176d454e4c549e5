"""What the held-out evaluation costs: N policies x L held-out lane changes, wall time.

    python -m benchmarks.heldout_cost runs/s3 --policies 72 --lane-changes 1000

The policies are the run's final checkpoints, repeated until there are N (each row is a real
rollout: the same params on the same cases cost the same as different ones), plus the
scripted controller, exactly as ``python -m jaxlc.evaluate`` runs them
(``evaluate_policies`` over the held-out keys, in chunks of ``--chunk``, on the host devices
the command would take). Times the drawing of the cases (``cases_for_lane_changes``) and the
rollouts apart, the first call including compilation; writes ``OUT/cost.csv`` with the
machine's float32 matmul peak and the date.
"""

from __future__ import annotations

import argparse
import datetime
import platform
import time
from pathlib import Path

import jax

from benchmarks import RESULTS, write_csv
from jaxlc.evaluation.cases import cases_for_lane_changes, evaluate_policies
from jaxlc.evaluation.protocol import final_checkpoints, load_rows
from jaxlc.sim.env import action_dim
from jaxlc.sim.observation import OBS_DIM
from jaxlc.study import machine
from jaxlc.study.rundir import RunDir


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("run_dir", type=Path)
    ap.add_argument("--policies", type=int, default=72)
    ap.add_argument("--lane-changes", type=int, default=1000)
    ap.add_argument("--chunk", type=int, default=32)
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    cfg = RunDir(args.run_dir).load_config()
    # The host devices python -m jaxlc.evaluate would take for a chunk (before JAX starts).
    widths = (OBS_DIM, *cfg.ddpg.hidden, action_dim(cfg.env))
    product = machine.largest_product(int(1.4 * args.lane_changes), widths)
    machine.use_host_devices(machine.host_devices_for(args.chunk, product))
    _, loaded, metas = load_rows(args.run_dir, final_checkpoints(args.run_dir))
    ks = [m["k"] for m in metas[1:]]
    actors = [loaded[i % len(loaded)] for i in range(args.policies)]
    ks = [1] + [ks[i % len(ks)] for i in range(args.policies)]
    devices = len(jax.devices())
    t0 = time.perf_counter()
    keys, started = cases_for_lane_changes(cfg, args.lane_changes, seed=0)
    t_cases = time.perf_counter() - t0
    t0 = time.perf_counter()
    out, _, info = evaluate_policies(
        cfg, [None, *actors], ks, started=started, chunk=args.chunk, traced=0, devices=devices
    )
    t_roll = time.perf_counter() - t0
    peak = machine.matmul_peak_gflops()
    row = {
        "date": datetime.date.today().isoformat(),
        "machine": f"{platform.processor() or platform.machine()}, {jax.devices()[0].platform}",
        "devices": len(jax.devices()),
        "policies": args.policies + 1,
        "lane_changes": int(info["performed"].sum()),
        "cases": len(keys),
        "cases_s": round(t_cases, 1),
        "rollouts_s": round(t_roll, 1),
        "matmul_peak_gflops": round(peak),
        "jax": jax.__version__,
    }
    write_csv(args.out / "cost.csv", [row], append=True)
    print(row)


if __name__ == "__main__":
    main()
