"""Simulator throughput: env-steps/s with random actions, by number of parallel envs.

Each measurement is one jitted ``lax.scan`` of ``--steps`` steps of ``vmap(env.step)`` over
N envs (random actions and per-env keys drawn inside the scan, as a trainer would), timed
after compilation; the figure is the median of ``--repeats`` runs, in wall time and in the CPU
time of all the process's threads. ``--traffic`` names the traffics measured side by side:
``paper`` (the vehicles keep their lane and brake only for their leader), ``hazards``
(``env.mobil`` and ``env.braking`` on, at their defaults), and ``braking`` or ``mobil`` (one
of the two alone: which one costs what).

``--hashes`` measures nothing: it prints the hashes of the simulator's programs, the lowered
(StableHLO) text of a vmapped ``env.step`` and ``env.reset`` over 8 envs, source locations
stripped, in the paper and the hazard traffic. Two commits whose hashes agree run the same
programs: the same rollouts and the same speed, whatever the machine's load.

    python -m benchmarks.sim_throughput                       # N = 1, 64, 1024, 4096, 16384
    python -m benchmarks.sim_throughput --envs 1 64 --steps 200 --repeats 2
    python -m benchmarks.sim_throughput --envs 4096 --traffic paper hazards
    python -m benchmarks.sim_throughput --hashes
"""

from __future__ import annotations

import argparse
import hashlib
import platform
import re
import statistics
import time
from datetime import date
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxlc
from benchmarks import RESULTS, write_csv
from jaxlc import config

# The traffics by name: the config overrides that make each.
TRAFFIC = {
    "paper": (),
    "braking": ("env.braking=true",),
    "mobil": ("env.mobil=true",),
    "hazards": ("env.mobil=true", "env.braking=true"),
}


def _digest(f, *args) -> str:
    text = jax.jit(f).lower(*args).as_text(debug_info=False)
    return hashlib.sha256(re.sub(r"loc\([^)]*\)", "", text).encode()).hexdigest()[:16]


def _programs(traffic: str, keys: jax.Array) -> dict[str, str]:
    """``{"step" | "reset": sha256 prefix}`` of a traffic's programs over ``keys`` (envs,)."""
    env, p = jaxlc.make(config.load(overrides=TRAFFIC[traffic]))
    _, s = jax.vmap(lambda k: env.reset(k, p, traffic_only=True))(keys)
    step = jax.vmap(lambda k, st: env.step(k, st, jnp.zeros(1), p))
    reset = jax.vmap(lambda k: env.reset(k, p))
    return {"step": _digest(step, keys, s), "reset": _digest(reset, keys)}


def hashes(envs: int = 8) -> dict[str, str]:
    """``{"<traffic> <program>": sha256 prefix}`` in the paper and the hazard traffic."""
    keys = jax.random.split(jax.random.PRNGKey(0), envs)
    return {f"{t} {k}": v for t in ("paper", "hazards") for k, v in _programs(t, keys).items()}


def make_runner(env, params, n_envs: int, steps: int):
    """A jitted ``(state, key) -> (state, rl_steps)`` scanning ``steps`` env-steps."""

    def body(state, key):
        k_act, k_env = jax.random.split(key)
        action = jax.random.uniform(k_act, (n_envs, 1), minval=-1.0, maxval=1.0)
        keys = jax.random.split(k_env, n_envs)
        _, state, _, _, _, info = jax.vmap(env.step, (0, 0, 0, None))(keys, state, action, params)
        return state, jnp.sum(info["rl_step"])

    @jax.jit
    def run(state, key):
        state, rl = jax.lax.scan(body, state, jax.random.split(key, steps))
        return state, rl.sum()

    return run


def measure(n_envs: int, steps: int, repeats: int, traffic: str = "paper") -> dict[str, float]:
    env, params = jaxlc.make(config.load(overrides=TRAFFIC[traffic]))
    _, state = jax.jit(jax.vmap(env.reset, (0, None)))(
        jax.random.split(jax.random.PRNGKey(0), n_envs), params
    )
    run = make_runner(env, params, n_envs, steps)
    t0 = time.perf_counter()
    state, rl = jax.block_until_ready(run(state, jax.random.PRNGKey(1)))
    compile_s = time.perf_counter() - t0
    times, cpu = [], []
    for r in range(repeats):
        t0, c0 = time.perf_counter(), time.process_time()
        state, rl = jax.block_until_ready(run(state, jax.random.PRNGKey(2 + r)))
        times.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    med = statistics.median(times)
    return {
        "traffic": traffic,
        "envs": n_envs,
        "steps": steps,
        "median_s": med,
        "env_steps_per_s": n_envs * steps / med,
        # CPU time of every thread: on a shared machine it varies far less than wall time
        "env_steps_per_cpu_s": n_envs * steps / statistics.median(cpu),
        "rl_share": float(rl) / (n_envs * steps),
        "first_call_s": compile_s,
    }


def main(argv: list[str] | None = None) -> list[dict[str, float]]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--envs", type=int, nargs="+", default=[1, 64, 1024, 4096, 16384])
    ap.add_argument("--steps", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--traffic", nargs="+", choices=list(TRAFFIC), default=["paper"])
    ap.add_argument("--csv", type=Path, default=RESULTS / "sim_throughput.csv")
    ap.add_argument("--hashes", action="store_true", help="print the programs' hashes, only")
    args = ap.parse_args(argv)
    if args.hashes:
        for k, v in hashes().items():
            print(k, v)
        return []

    print(
        f"jaxlc simulator throughput | {platform.processor() or platform.machine()} | "
        f"{jax.devices()[0].device_kind} x{jax.device_count()} | jax {jax.__version__} | "
        f"{date.today()}"
    )
    print(
        f"{'traffic':>8} {'envs':>7} {'env-steps/s':>14} {'per CPU-s':>12} {'median s':>9} "
        f"{'RL share':>9} {'first call s':>13}"
    )
    rows = []
    for n in args.envs:
        for traffic in args.traffic:
            row = measure(n, args.steps, args.repeats, traffic)
            rows.append(row)
            print(
                f"{traffic:>8} {n:>7} {row['env_steps_per_s']:>14,.0f} "
                f"{row['env_steps_per_cpu_s']:>12,.0f} {row['median_s']:>9.3f} "
                f"{row['rl_share']:>9.2f} {row['first_call_s']:>13.1f}",
                flush=True,
            )
    best = max(rows, key=lambda r: r["env_steps_per_s"])
    print(f"best: {best['env_steps_per_s']:,.0f} env-steps/s at N = {best['envs']}")
    write_csv(args.csv, rows)
    return rows


if __name__ == "__main__":
    main()
