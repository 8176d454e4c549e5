"""How many of a lane's ring slots (``env.slots_per_lane``) the traffic fills: the most vehicles
any lane held at once, over ``--envs`` highways × ``--steps`` env-steps driven by the scripted
controller (``jaxlc.sim.controller.scripted_action``), from ``reset`` on (its warm-up included).

    python benchmarks/scripts/lane_occupancy.py \
        --out benchmarks/bench_cpu_2026-11-24/lane_occupancy.csv
    python benchmarks/scripts/lane_occupancy.py env.inflow_min=1600 env.inflow_max=1600

A lane whose ring is full makes its next vehicle wait at the entry (the entry test of
``jaxlc.sim.env``), so a count that reaches the slot count means delayed entries, not a wrong
simulation. Writes one CSV row per run: the config overrides, env-steps, the largest count, and
the share of (env, lane, step) samples at each count from the slot count minus 2 up.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from csvfile import write_csv

import jaxlc
from jaxlc import config
from jaxlc.sim.controller import scripted_action


def occupancy(cfg: config.Config, envs: int, steps: int, seed: int) -> np.ndarray:
    """``(slots + 1,)`` counts of (env, lane, step) samples by vehicles on the lane."""
    env, params = jaxlc.make(cfg)
    slots = cfg.env.slots_per_lane

    def body(carry, key):
        obs, state = carry
        action = jax.vmap(scripted_action, (0, None))(obs, params)
        keys = jax.random.split(key, envs)
        obs, state, *_ = jax.vmap(env.step, (0, 0, 0, None))(keys, state, action, params)
        n = jnp.sum(state.traffic.active, axis=-1)  # (envs, lanes)
        return (obs, state), jnp.bincount(n.ravel(), length=slots + 1)

    @jax.jit
    def run(key):
        k_reset, k_steps = jax.random.split(key)
        obs, state = jax.vmap(env.reset, (0, None))(jax.random.split(k_reset, envs), params)
        _, hist = jax.lax.scan(body, (obs, state), jax.random.split(k_steps, steps))
        return hist.sum(axis=0)

    return np.asarray(run(jax.random.PRNGKey(seed)))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", type=Path, default=config.CONFIG_DIR / "default.toml")
    ap.add_argument("--envs", type=int, default=512)
    ap.add_argument("--steps", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=None, help="append the row to this CSV")
    ap.add_argument("overrides", nargs="*", help="table.key=value")
    args = ap.parse_args(argv)
    cfg = config.load(args.config, args.overrides)
    hist = occupancy(cfg, args.envs, args.steps, args.seed)
    slots, total = cfg.env.slots_per_lane, hist.sum()
    row = {
        "config": args.config.name,
        "overrides": " ".join(args.overrides),
        "env_steps": args.envs * args.steps,
        "slots_per_lane": slots,
        "max_vehicles": int(np.nonzero(hist)[0].max()),
        **{f"share_{n}": float(hist[n] / total) for n in range(slots - 2, slots + 1)},
    }
    print(", ".join(f"{k} {v}" for k, v in row.items()))
    if args.out is not None:
        write_csv(args.out, [row], append=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
