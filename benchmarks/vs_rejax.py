"""Rejax's learners, unmodified, on the lane-change task (``jaxlc.make_gymnax``), beside
jaxlc's DDPG: evaluated success on the 100 fixed cases, wall time, decisions/s, seeds.

Each algorithm is ``rejax.get_algo(name).create(env=env, env_params=params, ...)`` with
Rejax's defaults except ``gamma = 0.98`` (the task's), ``--timesteps`` RL decisions per seed
and the settings in ``HYPER``; its ``train`` runs vmapped over ``--seeds`` seeds in one jitted
call, compiled ahead so that the compile time is reported apart. Every seed's final policy
then drives the same 100 fixed cases as jaxlc's checkpoints
(``jaxlc.evaluation.cases.evaluate_act``), with its deterministic action (the Gaussian's mean,
squashed for SAC; TD3's actor as it is), beside the untrained policy of the same learner.
Success is over the cases that reached a lane change; the interval is a 95% bootstrap over
seeds (``jaxlc.evaluation.stats.describe``).

    python benchmarks/vs_rejax.py                                  # ppo sac td3, 3 seeds, 1M
    python benchmarks/vs_rejax.py --algos ppo --seeds 5 --timesteps 2000000
    python benchmarks/vs_rejax.py --tiny                           # seconds, for tests

Needs ``pip install -e ".[ecosystem]"``. Writes ``benchmarks/results/vs_rejax.csv``.
"""

from __future__ import annotations

import argparse
import platform
import sys
import time
from collections.abc import Callable, Sequence
from datetime import date
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT / "benchmarks"))

import jaxlc  # noqa: E402
from jaxlc import config  # noqa: E402
from jaxlc.evaluation import cases, results, stats  # noqa: E402
from jaxlc.study import machine  # noqa: E402

# Beyond Rejax's defaults: the task's discount (set in run), PPO's reward normalisation
# (returns reach -2,000 here), and batch sizes for a 14-d task.
HYPER: dict[str, dict[str, Any]] = {
    "ppo": {
        "num_envs": 16,
        "num_steps": 128,
        "num_epochs": 8,
        "num_minibatches": 8,
        "normalize_rewards": True,
    },
    "sac": {"num_envs": 8, "buffer_size": 100_000, "fill_buffer": 1_000, "batch_size": 256},
    "td3": {"num_envs": 8, "buffer_size": 100_000, "fill_buffer": 1_000, "batch_size": 256},
}


def greedy(name: str, algo: Any, ts: Any) -> Callable[[jax.Array], jax.Array]:
    """``obs (n, 14) -> action (n, 1)``: the policy without exploration."""
    params = ts.actor_ts.params

    if name == "td3":

        def head(m: Any, o: jax.Array) -> jax.Array:
            return m(o)
    elif name == "ppo":

        def head(m: Any, o: jax.Array) -> jax.Array:
            return jnp.clip(m.action_mean(m.features(o)), *m.action_range)
    else:  # sac: the squashed mean

        def head(m: Any, o: jax.Array) -> jax.Array:
            return m.action_loc + jnp.tanh(m.action_mean(m.features(o))) * m.action_scale

    def act(obs: jax.Array) -> jax.Array:
        if getattr(algo, "normalize_observations", False):
            obs = algo.normalize_obs(ts.obs_rms_state, obs)
        return jnp.reshape(algo.actor.apply(params, obs, method=head), (obs.shape[0], 1))

    return act


def evaluate(cfg: config.Config, name: str, algo: Any, ts: Any) -> dict[str, Any]:
    """The result row (``jaxlc.evaluation.results``) of one trained state's greedy policy."""
    out = cases.evaluate_act(cfg, greedy(name, algo, ts))
    return results.summarise(out, cfg.env.dt)[0]


def run(name: str, seeds: int, timesteps: int, cfg: config.Config) -> dict[str, Any]:
    import rejax

    env, params = jaxlc.make_gymnax(cfg)
    hyper = {**HYPER[name], "gamma": 0.98, "total_timesteps": timesteps, "eval_freq": timesteps}
    if name != "ppo":
        hyper["fill_buffer"] = min(hyper["fill_buffer"], timesteps // 2)
    algo = rejax.get_algo(name).create(env=env, env_params=params, **hyper)
    # Rejax's own evaluation (128 fresh roads at each eval_freq) is replaced by the fixed
    # cases below: a callback is configuration, the learner is untouched.
    algo = algo.replace(eval_callback=lambda algo, ts, key: ())
    train = jax.jit(jax.vmap(algo.train))
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    t0 = time.perf_counter()
    compiled = train.lower(keys).compile()
    t1 = time.perf_counter()
    ts, _ = jax.block_until_ready(compiled(keys))
    wall = time.perf_counter() - t1
    success, ret = [], []
    for s in range(seeds):
        row = evaluate(cfg, name, algo, jax.tree.map(lambda a, s=s: a[s], ts))
        success.append(row["success_rate"])
        ret.append(row["avg_return"])
    untrained = evaluate(cfg, name, algo, algo.init_state(jax.random.PRNGKey(0)))
    d = stats.describe(np.asarray(success))
    return {
        "learner": f"rejax {name}",
        "seeds": seeds,
        "decisions_per_seed": timesteps,
        "success_mean": d["mean"],
        "success_lo": d["mean_lo"],
        "success_hi": d["mean_hi"],
        "success_per_seed": " ".join(f"{x:.2f}" for x in success),
        "return_mean": float(np.mean(ret)),
        "untrained_success": untrained["success_rate"],
        "untrained_return": untrained["avg_return"],
        "train_s": round(wall, 1),
        "compile_s": round(t1 - t0, 1),
        "decisions_per_s": round(seeds * timesteps / wall),
    }


def main(argv: Sequence[str] | None = None) -> list[dict[str, Any]]:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--algos", nargs="+", default=["ppo", "sac", "td3"], choices=list(HYPER))
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--timesteps", type=int, default=1_000_000, help="RL decisions per seed")
    ap.add_argument("--csv", type=Path, default=ROOT / "benchmarks" / "results" / "vs_rejax.csv")
    ap.add_argument("--tiny", action="store_true", help="16k decisions, one seed (tests)")
    args = ap.parse_args(argv)
    if args.tiny:
        args.seeds, args.timesteps = 1, 16_384
    from sim_throughput import write_csv

    cfg = config.load()
    peak = machine.matmul_peak_gflops()
    rows = []
    for name in args.algos:
        row = run(name, args.seeds, args.timesteps, cfg)
        row |= {"machine": platform.processor() or platform.machine(), "date": str(date.today())}
        rows.append(row | {"matmul_peak_gflops": round(peak)})
        print({k: row[k] for k in ("learner", "success_mean", "success_lo", "success_hi",
                                   "return_mean", "untrained_return", "train_s",
                                   "decisions_per_s")}, flush=True)  # fmt: skip
    write_csv(args.csv, rows)
    print(f"wrote {args.csv} (matmul peak {peak:.0f} GFLOP/s)")
    return rows


if __name__ == "__main__":
    main()
