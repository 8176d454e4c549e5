"""A traffic's rollout, every leaf: 256 envs x 300 steps with random actions, the final state
and each step's outputs saved to an ``.npz``; ``--compare`` counts the leaves of two such
files that differ (exact, NaN equal to NaN).

    python rollout_leaves.py hazards before.npz       # on one commit (PYTHONPATH=<worktree>)
    python rollout_leaves.py hazards after.npz        # on another
    python rollout_leaves.py --compare before.npz after.npz
"""

from __future__ import annotations

import sys
from pathlib import Path

import jax
import numpy as np

import jaxlc
from jaxlc import config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from sim_throughput import TRAFFIC as _NAMED  # noqa: E402  (the traffics by name)

TRAFFIC = {
    "hazards": _NAMED["hazards"],
    # MOBIL ten times as often, no politeness, braking 300 times as often: rows fill, lane
    # changes and clashes between starters happen every few steps
    "busy": (
        *_NAMED["hazards"],
        "env.mobil_rate=5",
        "env.braking_rate=600",
        "env.mobil_politeness=0",
    ),
}
ENVS, STEPS = 256, 300


def rollout(name: str, out: str) -> None:
    env, p = jaxlc.make(config.load(overrides=list(TRAFFIC[name])))
    keys = jax.random.split(jax.random.PRNGKey(0), ENVS)
    _, st = jax.jit(jax.vmap(env.reset, (0, None)))(keys, p)

    def body(s, k):
        ks = jax.random.split(k, ENVS)
        act = jax.vmap(lambda kk: jax.random.uniform(kk, (1,), minval=-1, maxval=1))(ks)
        obs, s, r, term, trunc, info = jax.vmap(env.step, (0, 0, 0, None))(ks, s, act, p)
        return s, (obs, r, term, trunc, info)

    run = jax.jit(lambda s: jax.lax.scan(body, s, jax.random.split(jax.random.PRNGKey(5), STEPS)))
    leaves = jax.tree_util.tree_leaves_with_path(run(st))
    np.savez(out, **{jax.tree_util.keystr(k): np.asarray(v) for k, v in leaves})
    print(f"{name}: {len(leaves)} leaves -> {out}")


def compare(a: str, b: str) -> None:
    x, y = np.load(a), np.load(b)
    assert set(x.files) == set(y.files), set(x.files) ^ set(y.files)
    differ = [k for k in x.files if not np.array_equal(x[k], y[k], equal_nan=True)]
    print(f"{len(x.files)} leaves, {len(differ)} differ {differ[:10]}")


if __name__ == "__main__":
    if sys.argv[1] == "--compare":
        compare(sys.argv[2], sys.argv[3])
    else:
        rollout(sys.argv[1], sys.argv[2])
