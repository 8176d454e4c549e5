"""Rejax's learners, unmodified, on the lane-change task (``jaxlc.make_gymnax``), beside
jaxlc's DDPG: evaluated success on the fixed cases, wall time, decisions/s, seeds.

Each algorithm is ``rejax.get_algo(name).create(env=FiveValueAdapter(env),
env_params=params, ...)`` (Rejax 0.1.3 unpacks gymnax 0.0.x's five step values;
``jaxlc.gymnax_env``) with Rejax's defaults except ``gamma = 0.98`` (the task's),
``--timesteps`` RL decisions per seed and the settings in ``HYPER``; its ``train`` runs
vmapped over ``--seeds`` seeds in one jitted call, compiled ahead so that the compile time
is reported apart. Every seed's final policy then drives the first ``--cases`` fixed cases
(the protocol's 100), as jaxlc's checkpoints do (``jaxlc.evaluation.cases.evaluate_act``),
with its deterministic action (the Gaussian's mean, squashed for SAC; TD3's actor as it is),
beside the untrained policies of the same learner (each seed's initial one; the mean over
seeds is reported). Success is over the cases that reached a lane change; the interval is a
95% bootstrap over seeds (``jaxlc.evaluation.stats.describe``).

    python -m benchmarks.vs_rejax                          # ppo sac td3, 3 seeds, 1M
    python -m benchmarks.vs_rejax --algos ppo --seeds 5 --timesteps 2000000
    python -m benchmarks.vs_rejax --tiny                           # seconds, for tests

Needs ``pip install -e ".[ecosystem]"``. Writes ``benchmarks/results/vs_rejax.csv``.
"""

from __future__ import annotations

import argparse
import platform
import time
from collections.abc import Callable, Sequence
from datetime import date
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

import jaxlc
from benchmarks import RESULTS, write_csv
from jaxlc import config
from jaxlc.evaluation import cases, results, stats
from jaxlc.evaluation import keys as streams
from jaxlc.study import machine

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


# Each learner's deterministic action from its actor module ``m`` on observations ``o``.
HEADS: dict[str, Callable[[Any, jax.Array], jax.Array]] = {
    "td3": lambda m, o: m(o),
    "ppo": lambda m, o: jnp.clip(m.action_mean(m.features(o)), *m.action_range),
    "sac": lambda m, o: m.action_loc + jnp.tanh(m.action_mean(m.features(o))) * m.action_scale,
}


def greedy(name: str, algo: Any) -> Callable[[Any, jax.Array], jax.Array]:
    """``(policy, obs (n, 14)) -> action (n, 1)``: the policy without exploration, where
    ``policy`` is ``policy_of`` a train state (params are an argument, not constants, so one
    compiled rollout serves every seed and the untrained policy)."""

    def act(policy: Any, obs: jax.Array) -> jax.Array:
        params, obs_rms = policy
        if obs_rms is not None:
            obs = algo.normalize_obs(obs_rms, obs)
        return jnp.reshape(algo.actor.apply(params, obs, method=HEADS[name]), (obs.shape[0], 1))

    return act


def policy_of(algo: Any, ts: Any) -> tuple[Any, Any]:
    """What ``greedy``'s policy reads from a train state: actor params, observation stats."""
    normalize = getattr(algo, "normalize_observations", False)
    return ts.actor_ts.params, ts.obs_rms_state if normalize else None


def evaluate(
    cfg: config.Config, name: str, algo: Any, policies: list[Any], n_cases: int
) -> list[dict[str, Any]]:
    """The result rows (``jaxlc.evaluation.results``) of greedy policies on the first
    ``n_cases`` fixed cases of ``jaxlc.evaluation.cases.evaluate_act``, all in one compiled
    rollout vmapped over the policies."""
    max_steps, n = cases.PROTOCOL.max_steps, len(policies)
    start, _ = cases.programs(cfg, max_steps)  # the checkpoints' own (cached) case program
    rollout = jax.jit(cases.make_rollout(jaxlc.make(cfg)[1], greedy(name, algo), max_steps))
    cs = start(streams.stream(0, streams.PROTOCOL, range(n_cases)))
    pol = cases.Policies(
        actor=jax.tree.map(lambda *xs: jnp.stack(xs), *policies),
        k=jnp.ones(n, jnp.int32),
        scripted=jnp.zeros(n, bool),
    )
    out, _ = jax.device_get(rollout(pol, cs, jnp.zeros(1, jnp.int32)))
    return results.summarise({k: np.asarray(v) for k, v in cases.columns(out).items()}, cfg.env.dt)


def run(name: str, seeds: int, timesteps: int, cfg: config.Config, n_cases: int) -> dict[str, Any]:
    import rejax

    from jaxlc.gymnax_env import FiveValueAdapter

    env, params = jaxlc.make_gymnax(cfg)
    hyper = {**HYPER[name], "gamma": 0.98, "total_timesteps": timesteps, "eval_freq": timesteps}
    if name != "ppo":
        hyper["fill_buffer"] = min(hyper["fill_buffer"], timesteps // 2)
    algo = rejax.get_algo(name).create(env=FiveValueAdapter(env), env_params=params, **hyper)
    # Rejax's own evaluation (128 fresh roads at each eval_freq) is replaced by the fixed
    # cases below: a callback is configuration, the learner is untouched.
    algo = algo.replace(eval_callback=lambda algo, ts, key: ())

    def train_seed(key: jax.Array) -> tuple[Any, Any]:
        # Rejax's train(key) is train(train_state=init_state(key)); returning the initial
        # policy too gives the untrained baseline without another compile of the env's reset.
        ts0 = algo.init_state(key)
        return algo.train(train_state=ts0)[0], policy_of(algo, ts0)

    train = jax.jit(jax.vmap(train_seed))
    keys = jax.random.split(jax.random.PRNGKey(0), seeds)
    t0 = time.perf_counter()
    compiled = train.lower(keys).compile()
    t1 = time.perf_counter()
    ts, initial = jax.block_until_ready(compiled(keys))
    wall = time.perf_counter() - t1
    final = policy_of(algo, ts)
    policies = [
        jax.tree.map(lambda a, s=s: a[s], p) for p in (final, initial) for s in range(seeds)
    ]
    rows = evaluate(cfg, name, algo, policies, n_cases)
    success = [row["success_rate"] for row in rows[:seeds]]
    ret = [row["avg_return"] for row in rows[:seeds]]
    untrained = {
        k: float(np.mean([row[k] for row in rows[seeds:]])) for k in ("success_rate", "avg_return")
    }
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
    ap.add_argument("--cases", type=int, default=cases.PROTOCOL.cases, help="fixed cases")
    ap.add_argument("--csv", type=Path, default=RESULTS / "vs_rejax.csv")
    ap.add_argument("--tiny", action="store_true", help="16k decisions, one seed (tests)")
    args = ap.parse_args(argv)
    if args.tiny:
        args.seeds, args.timesteps = 1, 16_384
    cfg = config.load()
    peak = machine.matmul_peak_gflops()
    rows = []
    for name in args.algos:
        row = run(name, args.seeds, args.timesteps, cfg, args.cases)
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
