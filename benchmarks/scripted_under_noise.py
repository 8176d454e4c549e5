"""How often the scripted controller completes its lane changes under the training noise.

Training success rates are measured with exploration noise on (truncated normal, sigma in tanh
units, held for k steps like every action), so even a good controller cannot reach 100%
there. This script runs ``jaxlc.sim.controller.scripted_action`` plus ``jaxlc.learn.ddpg.explore``
noise, for each action-update step k and noise sigma, in N parallel envs of the paper's
simulator, and counts how the lane changes end: the ceiling a learned policy is judged
against in training.

    python -m benchmarks.scripted_under_noise                 # k 1 2 4 x sigma 0 0.1 0.2
    python -m benchmarks.scripted_under_noise --k 1 --sigma 0.2 --envs 64 --steps 500
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import RESULTS, write_csv
from jaxlc import config
from jaxlc.learn.ddpg import explore
from jaxlc.sim.controller import scripted_action
from jaxlc.sim.env import EnvParams, LaneChangeEnv
from jaxlc.sim.reward import COLLISION, NO_GAP, OUT_OF_BOUNDS, SUCCESS, TIMEOUT


def make_runner(cfg: config.Config, n_envs: int, steps: int):
    """Jitted ``(key, k, sigma) -> (steps, envs) reason codes`` of RL steps (0 elsewhere)."""
    env = LaneChangeEnv()
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)

    @jax.jit
    def run(key, k, sigma):
        p = base.replace(k=k)
        k_reset, k_run = jax.random.split(key)
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(k_reset, n_envs), p)

        def body(carry, key):
            obs, state = carry
            k_noise, k_env = jax.random.split(key)
            action = explore(k_noise, scripted_action(obs, p), sigma, cfg.ddpg.noise_clip)
            keys = jax.random.split(k_env, n_envs)
            obs, state, _, _, _, info = jax.vmap(env.step, (0, 0, 0, None))(keys, state, action, p)
            return (obs, state), jnp.where(info["rl_step"], info["reason"], 0)

        _, reasons = jax.lax.scan(body, (obs, state), jax.random.split(k_run, steps))
        return reasons

    return run


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=int, nargs="+", default=[1, 2, 4])
    ap.add_argument("--sigma", type=float, nargs="+", default=[0.0, 0.1, 0.2])
    ap.add_argument("--envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=3000, help="env-steps per env")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--csv", type=Path, default=RESULTS / "scripted_under_noise.csv")
    args = ap.parse_args(argv)

    run = make_runner(config.load(), args.envs, args.steps)
    rows = []
    print(f"{'k':>3} {'sigma':>6} {'lane changes':>13} {'success':>8} {'timeout':>8} {'out':>6}")
    for k in args.k:
        for sigma in args.sigma:
            r = np.asarray(run(jax.random.PRNGKey(args.seed), jnp.int32(k), jnp.float32(sigma)))
            ends = r[(r != 0) & (r != NO_GAP)]
            n = max(len(ends), 1)
            row = {
                "k": k,
                "sigma": sigma,
                "lane_changes": len(ends),
                "success": int(np.sum(ends == SUCCESS)),
                "timeout": int(np.sum(ends == TIMEOUT)),
                "out_of_bounds": int(np.sum(ends == OUT_OF_BOUNDS)),
                "collision": int(np.sum(ends == COLLISION)),
                "success_rate": float(np.sum(ends == SUCCESS)) / n,
            }
            rows.append(row)
            print(
                f"{k:>3} {sigma:>6.2f} {len(ends):>13} {row['success_rate']:>8.2%} "
                f"{row['timeout'] / n:>8.2%} {row['out_of_bounds'] / n:>6.2%}"
            )
    write_csv(args.csv, rows)
    print(f"wrote {args.csv}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
