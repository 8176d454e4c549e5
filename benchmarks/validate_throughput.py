"""Crude Monte Carlo's speed: lane changes per second, and its env-steps/s against the
simulator's own (``sim_throughput.py``) at the same number of envs.

    python -m benchmarks.validate_throughput --chunk 2048 --traffic paper braking

One chunk of ``--chunk`` lane-change cases of the scripted controller, as ``python -m
jaxlc.validate --method mc`` runs them (``jaxlc.evaluation.validation.program``: every case
reset with its traffic-only warm-up, its approach (``cases.make_start_cases``), its manoeuvre
(``cases.make_rollout``)), median of ``--repeats`` after compiling. Its env-steps are the
steps its cases needed (warm-up, approach, manoeuvre; the warm-up's are the traffic's alone);
beside them the scan of ``sim_throughput.py`` at ``--chunk`` envs, in the same process.
``--chain 1 8``: also each case driving 8 lane changes in one traffic (``validate --chain``;
its env-steps are not counted: the later lane changes' approaches are not returned).
Writes ``OUT/throughput.csv`` with the matmul peak before and after.
"""

from __future__ import annotations

import argparse
import datetime
import statistics
import time
from pathlib import Path

import jax
import numpy as np

from benchmarks import RESULTS, sim_throughput, write_csv
from jaxlc import config
from jaxlc.evaluation import heldout, validation
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation.cases import columns, make_start_cases
from jaxlc.sim.env import EnvParams
from jaxlc.study import machine

TRAFFIC = sim_throughput.TRAFFIC  # the traffics by name: the simulator benchmark's


def mc_chunk(traffic: str, chunk: int, repeats: int, chain: int = 1) -> dict:
    cfg = heldout.in_traffic(config.load(), TRAFFIC[traffic])
    base = EnvParams.from_config(cfg.env)
    run = validation.program(cfg, config.EvalConfig().max_steps, False, chain)
    start = jax.jit(make_start_cases(base, config.EvalConfig().max_steps, traffic_warmup=True))
    pol = validation.policies(cfg, None, 1)
    times, lcs, steps = [], [], []
    for r in range(repeats + 1):
        keys = streams.stream(r, streams.VALIDATE, range(chunk))
        t0 = time.perf_counter()
        out = columns(jax.device_get(run(None, pol, keys)[0]))
        times.append(time.perf_counter() - t0)
        lcs.append(int(out["performed"][0].sum()))
        if chain == 1:
            approach = np.asarray(start(keys).state.time)  # the same cases' approach, untimed
            steps.append(int(chunk * base.warmup_steps + approach.sum() + out["steps"][0].sum()))
    i = int(np.argsort(times[1:])[len(times[1:]) // 2]) + 1  # the median repeat
    return {
        "traffic": traffic,
        "envs": chunk,
        "chain": chain,
        "lane_changes": lcs[i],
        "median_s": round(times[i], 3),
        "lane_changes_per_s": round(lcs[i] / times[i], 1),
        "env_steps_per_s": round(steps[i] / times[i]) if steps else "",
        "first_call_s": round(times[0], 1),
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--chunk", type=int, default=2048)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--steps", type=int, default=200, help="sim_throughput's scan length")
    ap.add_argument("--traffic", nargs="+", default=["paper", "braking"], choices=TRAFFIC)
    ap.add_argument("--chain", type=int, nargs="+", default=[1], help="lane changes per case")
    ap.add_argument("--out", type=Path, default=RESULTS)
    args = ap.parse_args()
    peak0 = machine.matmul_peak_gflops()
    rows = []
    for t in args.traffic:
        s = sim_throughput.measure(args.chunk, args.steps, args.repeats, t)["env_steps_per_s"]
        for chain in args.chain:
            mc = mc_chunk(t, args.chunk, args.repeats, chain)
            mc["sim_env_steps_per_s"] = round(s)
            mc["share_of_sim"] = round(mc["env_steps_per_s"] / s, 3) if chain == 1 else ""
            rows.append(mc)
            print(mc, flush=True)
    peak1 = machine.matmul_peak_gflops()
    today = datetime.date.today().isoformat()
    for r in rows:
        r |= {"matmul_peak_before": round(peak0), "matmul_peak_after": round(peak1), "date": today}
    write_csv(args.out / "throughput.csv", rows)
    shares = [r["share_of_sim"] for r in rows if r["chain"] == 1]
    print("median share of the simulator:", statistics.median(shares) if shares else "-")


if __name__ == "__main__":
    main()
