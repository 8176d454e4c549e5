"""Hashes of the simulator's compiled-to-be programs: the lowered (StableHLO) text of a
vmapped ``env.step`` and ``env.reset``, source locations stripped, in the paper's traffic and
in the hazard traffic (``env.mobil`` and ``env.braking`` on). Two commits whose hashes agree
run the same programs: the same rollouts and the same speed, whatever the machine's load.

    python -m benchmarks.program_hashes
"""

from __future__ import annotations

import argparse
import hashlib
import re

import jax
import jax.numpy as jnp

import jaxlc
from jaxlc import config

TRAFFICS = {"paper": (), "hazards": ("env.mobil=true", "env.braking=true")}


def _digest(f, *args) -> str:
    text = jax.jit(f).lower(*args).as_text(debug_info=False)
    return hashlib.sha256(re.sub(r"loc\([^)]*\)", "", text).encode()).hexdigest()[:16]


def hashes(envs: int = 8) -> dict[str, str]:
    """``{"<traffic> <program>": sha256 prefix}`` of the step and reset programs."""
    out = {}
    keys = jax.random.split(jax.random.PRNGKey(0), envs)
    for name, overrides in TRAFFICS.items():
        out |= {f"{name} {k}": v for k, v in _programs(overrides, keys).items()}
    return out


def _programs(overrides: tuple[str, ...], keys) -> dict[str, str]:
    env, p = jaxlc.make(config.load(overrides=overrides))
    _, s = jax.vmap(lambda k: env.reset(k, p, traffic_only=True))(keys)
    step = jax.vmap(lambda k, st: env.step(k, st, jnp.zeros(1), p))
    reset = jax.vmap(lambda k: env.reset(k, p))
    return {"step": _digest(step, keys, s), "reset": _digest(reset, keys)}


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--envs", type=int, default=8, help="envs in the vmapped programs")
    for k, v in hashes(ap.parse_args(argv).envs).items():
        print(k, v)


if __name__ == "__main__":
    main()
