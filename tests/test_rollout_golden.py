"""The highway step's numbers are pinned: a long seeded rollout ends in the recorded state.

``tests/data/rollout_golden.npz`` was written by ``python -m tests.test_rollout_golden`` from
the single-body step that ``env._advance`` replaced (its phases are now separate functions);
the refactor moved code and changed no arithmetic, so the final state matches bit for bit.
It pins the simulator of ``configs/paper.toml`` (the paper's gap acceptance, no
time-to-collision test); ``configs/default.toml`` differs from it in ``env.gap_min_ttc``
alone, which ``tests/test_env.py`` checks on a hand-made gap. Regenerate it only for a
deliberate change of the simulator's dynamics, and say so.
"""

import os
import subprocess
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxlc
from jaxlc import config

from .conftest import HANG_GUARD_S, SUITE_XLA_FLAGS

# XLA's own defaults, named: the subprocess imports conftest, which sets the suite's otherwise
DEFAULT_XLA_FLAGS = ("--xla_backend_optimization_level=3", "--xla_cpu_use_fusion_emitters=true")

GOLDEN = Path(__file__).parent / "data" / "rollout_golden.npz"
ENVS, STEPS = 8, 3000


def rollout(traced: bool = False) -> dict[str, np.ndarray]:
    """``ENVS`` envs, ``STEPS`` steps of uniform random actions; final state and totals.
    ``traced``: the params are an argument of the jitted function, not constants in it."""
    env, closed = jaxlc.make(config.load(config.PAPER_CONFIG))

    def one(key, params):
        k_reset, k_run = jax.random.split(key)
        _, state = env.reset(k_reset, params)

        def body(carry, k):
            state, totals = carry
            k_act, k_step = jax.random.split(k)
            action = jax.random.uniform(k_act, (1,), minval=-1.0, maxval=1.0)
            _, state, r, term, trunc, info = env.step(k_step, state, action, params)
            totals = totals + jnp.stack(
                [r, term, trunc, info["rl_step"], info["lane_change"]]
            ).astype(jnp.float32)
            return (state, totals), None

        (state, totals), _ = jax.lax.scan(
            body, (state, jnp.zeros(5)), jax.random.split(k_run, STEPS)
        )
        return state, totals

    keys = jax.random.split(jax.random.key(2019), ENVS)
    if traced:
        state, totals = jax.jit(jax.vmap(one, (0, None)))(keys, closed)
    else:
        state, totals = jax.jit(jax.vmap(lambda k: one(k, closed)))(keys)
    leaves = jax.tree_util.tree_leaves_with_path(state)
    out = {jax.tree_util.keystr(path): np.asarray(leaf) for path, leaf in leaves}
    out["totals"] = np.asarray(totals)
    return out


def test_seeded_rollout_matches_the_recorded_final_state(tmp_path):
    want = np.load(GOLDEN)
    got = rollout()
    assert sorted(got) == sorted(want.files)
    # The run must have exercised manoeuvres, or the pin would say little.
    assert want["totals"][:, 1].sum() + want["totals"][:, 2].sum() > 0
    assert want["totals"][:, 4].sum() > 0
    for name in want.files:
        np.testing.assert_array_equal(got[name], want[name], err_msg=name)
    # The suite compiles with its own flags (tests/conftest.py); the pin is of the build a
    # user's program gets, XLA's defaults: that gives the recorded state too.
    out = tmp_path / "default_level.npz"
    flags = [f for f in os.environ.get("XLA_FLAGS", "").split() if f not in SUITE_XLA_FLAGS]
    flags += DEFAULT_XLA_FLAGS
    code = "import os, sys, numpy as np; from tests.test_rollout_golden import rollout; "
    code += "np.savez(sys.argv[1], **rollout(), xla_flags=os.environ['XLA_FLAGS'])"
    done = subprocess.run(
        [sys.executable, "-c", code, str(out)],
        cwd=GOLDEN.parents[2],
        env={**os.environ, "XLA_FLAGS": " ".join(flags)},
        capture_output=True,
        text=True,
        timeout=HANG_GUARD_S,
    )
    assert done.returncode == 0, done.stderr[-3000:]
    default = np.load(out)
    assert str(default["xla_flags"]).split()[-2:] == list(DEFAULT_XLA_FLAGS)
    for name in want.files:
        np.testing.assert_array_equal(default[name], want[name], err_msg=name)


def test_params_passed_traced_give_the_recorded_rollout():
    """A user may jit ``env.step`` with the params as an argument (and vmap over them): the
    same rollout. Every discrete leaf (phases, lanes, slots, step counts) is equal; real ones
    agree to float32 rounding, because closed over, products of params alone (``1 - gamma``,
    ``w3*dt``, the road's centre ``lanes*W/2``) are Python's doubles rounded once, and passed
    traced they are float32 products (measured: at most 3e-7 relative after 3,000 steps)."""
    want = np.load(GOLDEN)
    got = rollout(traced=True)
    for name in want.files:
        if want[name].dtype.kind == "f":
            np.testing.assert_allclose(got[name], want[name], rtol=1e-5, atol=1e-3, err_msg=name)
        else:
            np.testing.assert_array_equal(got[name], want[name], err_msg=name)


if __name__ == "__main__":
    np.savez(GOLDEN, **rollout())
    print(f"wrote {GOLDEN}")
