"""jaxlc vs highway-env: simulated env-steps/s on this CPU, both measured in the same run.

One env-step is 0.1 s of simulated traffic on both sides:

- highway-env: ``highway-v0`` with ``ContinuousAction``, 3 lanes, 20 vehicles and
  policy_frequency = simulation_frequency = 10 Hz (one ``step`` = one 0.1 s simulator step),
  random actions from its action space, episodes reset as they end (reset time counted, as a
  trainer sees it), no rendering. Measured as one env (``gym.make``) and as gymnasium vector
  envs (``--hw-vec``, e.g. ``async:2`` = AsyncVectorEnv with 2 worker processes); a vector
  step counts ``num_envs`` env-steps (its next-step autoreset steps included, which slightly
  favours highway-env). Each setting runs ``--seconds`` of wall time after a warm-up.
- jaxlc: ``benchmarks/sim_throughput.measure`` (a jitted ``lax.scan`` of ``vmap(env.step)``
  over N envs, random actions) at 1 env and at every ``--envs`` batch size: 3 lanes x 600 m,
  up to 48 vehicles, inflow 800-1600 veh/h/lane. Also the gym wrapper (``LaneChangeGymEnv``,
  one Python call per RL decision, random actions), reported as RL decisions/s and as the
  env-steps it simulated per second (RL steps plus the fast-forwarded ones).

Ratios: jaxlc at 1 env over highway-env's single env, and jaxlc's best batch over
highway-env's best setting. The table goes to stdout and a CSV to
``benchmarks/results/vs_highway_env.csv``.

    python -m benchmarks.vs_highway_env                  # ~3-4 min
    python -m benchmarks.vs_highway_env --tiny           # seconds, for tests
"""

from __future__ import annotations

import argparse
import functools
import os
import platform
import sys
import time
from datetime import date
from pathlib import Path
from typing import Any

import jax
import numpy as np

from benchmarks import csvfile, sim_throughput

ROOT = Path(__file__).resolve().parents[1]
RESULTS = ROOT / "benchmarks" / "results"
HIGHWAY_CONFIG = {
    "action": {"type": "ContinuousAction"},
    "lanes_count": 3,
    "vehicles_count": 20,
    "policy_frequency": 10,
    "simulation_frequency": 10,
}
# "module:id" makes gymnasium import highway_env (which registers highway-v0) in spawned workers.
HIGHWAY_ID = "highway_env:highway-v0"


def _load() -> str:
    return "/".join(f"{x:.2f}" for x in os.getloadavg())


def _with_load(fn: Any, *args: Any) -> dict[str, Any]:
    """``fn(*args)``'s row plus the 1-minute load average before and after it (this machine
    is shared; the async workers count in it too)."""
    before = os.getloadavg()[0]
    row = fn(*args)
    row["load_before"], row["load_after"] = before, os.getloadavg()[0]
    return row


def _make_highway_vec(kind: str, n: int) -> Any:
    import gymnasium as gym

    fns = [functools.partial(gym.make, HIGHWAY_ID, config=HIGHWAY_CONFIG) for _ in range(n)]
    if kind == "sync":
        return gym.vector.SyncVectorEnv(fns)
    # spawn, not fork: this process has JAX's threads running, and forking them can deadlock.
    return gym.vector.AsyncVectorEnv(fns, context="spawn")


def measure_highway(setting: str, seconds: float, seed: int = 0) -> dict[str, Any]:
    """env-steps/s of highway-env under ``setting``: "single", "sync:N" or "async:N"."""
    import gymnasium as gym

    if setting == "single":
        env, n = gym.make(HIGHWAY_ID, config=HIGHWAY_CONFIG), 1
    else:
        kind, n_str = setting.split(":")
        n = int(n_str)
        env = _make_highway_vec(kind, n)
    env.action_space.seed(seed)
    env.reset(seed=seed)
    steps = episodes = 0

    def run(limit: float) -> float:
        nonlocal steps, episodes
        t0 = time.perf_counter()
        while time.perf_counter() - t0 < limit:
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            steps += 1
            if setting == "single":
                if term or trunc:
                    episodes += 1
                    env.reset()
            else:
                episodes += int(np.sum(term | trunc))  # the vector env autoresets
        return time.perf_counter() - t0

    run(min(1.0, seconds))  # warm-up: imports, first episodes, worker start-up
    steps = episodes = 0
    elapsed = run(seconds)
    env.close()
    return {
        "simulator": "highway-env",
        "setting": setting,
        "envs": n,
        "env_steps_per_s": steps * n / elapsed,
        "decisions_per_s": steps * n / elapsed,
        "seconds": elapsed,
        "env_steps": steps * n,
        "episodes": episodes,
    }


def measure_jaxlc_gym(seconds: float, seed: int = 0) -> dict[str, Any]:
    """The gym wrapper with random actions: RL decisions/s and simulated env-steps/s."""
    from jaxlc.gym import LaneChangeGymEnv

    env = LaneChangeGymEnv()
    env.action_space.seed(seed)
    _, info = env.reset(seed=seed)
    env.step(env.action_space.sample())  # compile outside the timing
    _, info = env.reset(seed=seed)
    decisions, skipped, episodes = 0, info["skipped_steps"], 0
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        _, _, term, trunc, _ = env.step(env.action_space.sample())
        decisions += 1
        if term or trunc:
            episodes += 1
            _, info = env.reset()
            skipped += info["skipped_steps"]
    elapsed = time.perf_counter() - t0
    return {
        "simulator": "jaxlc",
        "setting": "gym wrapper",
        "envs": 1,
        "env_steps_per_s": (decisions + skipped) / elapsed,
        "decisions_per_s": decisions / elapsed,
        "seconds": elapsed,
        "env_steps": decisions + skipped,
        "episodes": episodes,
    }


def measure_jaxlc(n_envs: int, steps: int, repeats: int) -> dict[str, Any]:
    r = sim_throughput.measure(n_envs, steps, repeats)
    return {
        "simulator": "jaxlc",
        "setting": "scan+vmap" if n_envs > 1 else "scan",
        "envs": n_envs,
        "env_steps_per_s": r["env_steps_per_s"],
        "decisions_per_s": r["env_steps_per_s"] * r["rl_share"],
        "seconds": r["median_s"],
        "env_steps": n_envs * steps,
        "episodes": float("nan"),
    }


def main(argv: list[str] | None = None) -> dict[str, Any]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--seconds", type=float, default=20.0, help="per highway-env setting")
    ap.add_argument("--hw-vec", nargs="*", default=["sync:2", "async:2", "async:4"])
    ap.add_argument("--envs", type=int, nargs="+", default=[64, 1024, 4096])
    ap.add_argument("--steps", type=int, default=1000, help="jaxlc scan length")
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--csv", type=Path, default=RESULTS / "vs_highway_env.csv")
    ap.add_argument("--tiny", action="store_true", help="a few seconds in all, for tests")
    args = ap.parse_args(argv)
    if args.tiny:
        args.seconds, args.hw_vec, args.envs = 0.5, ["async:2"], []
        args.steps, args.repeats = 50, 1

    import highway_env  # noqa: F401  (fails here, clearly, when it is not installed)

    print(
        f"jaxlc vs highway-env {highway_env.__version__} | "
        f"{platform.processor() or platform.machine()}, {os.cpu_count()} cores | "
        f"jax {jax.__version__} on {jax.devices()[0].device_kind} | {date.today()} | "
        f"load {_load()}",
        flush=True,
    )
    rows = []
    for setting in ["single", *args.hw_vec]:
        rows.append(_with_load(measure_highway, setting, args.seconds))
        print(
            f"  highway-env {setting}: {rows[-1]['env_steps_per_s']:,.0f} env-steps/s", flush=True
        )
    rows.append(_with_load(measure_jaxlc_gym, args.seconds))
    for n in [1, *args.envs]:
        rows.append(_with_load(measure_jaxlc, n, args.steps, args.repeats))
        print(f"  jaxlc N={n}: {rows[-1]['env_steps_per_s']:,.0f} env-steps/s", flush=True)

    hw = [r for r in rows if r["simulator"] == "highway-env"]
    jx = [r for r in rows if r["simulator"] == "jaxlc" and r["setting"] != "gym wrapper"]
    hw_single, hw_best = hw[0], max(hw, key=lambda r: r["env_steps_per_s"])
    jx_single, jx_best = jx[0], max(jx, key=lambda r: r["env_steps_per_s"])
    print()
    print(
        f"{'simulator':<12} {'setting':<12} {'envs':>6} {'env-steps/s':>14} "
        f"{'decisions/s':>12} {'episodes':>9} {'load before/after':>18}"
    )
    for r in rows:
        eps = "" if r["episodes"] != r["episodes"] else f"{r['episodes']:,}"
        print(
            f"{r['simulator']:<12} {r['setting']:<12} {r['envs']:>6} "
            f"{r['env_steps_per_s']:>14,.0f} {r['decisions_per_s']:>12,.0f} {eps:>9} "
            f"{r['load_before']:>10.2f} / {r['load_after']:<5.2f}"
        )
    ratio_single = jx_single["env_steps_per_s"] / hw_single["env_steps_per_s"]
    ratio_best = jx_best["env_steps_per_s"] / hw_best["env_steps_per_s"]
    print(
        f"\n1 env:   jaxlc {jx_single['env_steps_per_s']:,.0f} / highway-env "
        f"{hw_single['env_steps_per_s']:,.0f} = {ratio_single:,.0f}x"
    )
    print(
        f"best:    jaxlc N={jx_best['envs']} {jx_best['env_steps_per_s']:,.0f} / highway-env "
        f"{hw_best['setting']} {hw_best['env_steps_per_s']:,.0f} = {ratio_best:,.0f}x"
    )
    csvfile.write_csv(args.csv, rows)
    print(f"wrote {args.csv}")
    return {
        "rows": rows,
        "ratio_single": ratio_single,
        "ratio_best": ratio_best,
        "highway_best": hw_best["env_steps_per_s"],
        "jaxlc_best": jx_best["env_steps_per_s"],
    }


if __name__ == "__main__":
    main(sys.argv[1:])
