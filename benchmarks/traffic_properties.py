"""The traffic that cuts in and brakes, checked over a long run: ``env.mobil`` and
``env.braking`` on (at their highest configured rates unless told otherwise), the scripted
controller driving the egos, every step checked for

- two non-ego bodies overlapping (boxes at their lateral positions, lane changes included);
- a negative speed, or a body past the road's edges;
- a lane change started where MOBIL's safety criterion forbids it: the new follower (the ego
  included), found by brute force in the state before the step, would brake harder than
  ``b_safe`` or stand closer than ``s0`` behind it;
- the rates: drivers weighing a lane change per eligible vehicle-step (a driver past the env's
  ``mobil_deciders`` on one step does not) and braking events per eligible vehicle-step against
  ``1 - exp(-rate * dt)``, with their 99.9% Clopper-Pearson intervals.

    python -m benchmarks.traffic_properties --envs 256 --steps 100000
    python -m benchmarks.traffic_properties --envs 64 --steps 400 --rates default
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from datetime import date
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

import jaxlc
from jaxlc import config
from jaxlc.evaluation.heldout import clopper_pearson
from jaxlc.sim.controller import scripted_action
from jaxlc.sim.idm import idm_with_params
from jaxlc.sim.leaders import changing, occupancy, vehicle_y
from jaxlc.sim.road import ego_lanes

HIGHEST = ("env.mobil_rate=10.0", "env.braking_rate=3600.0")  # the ranges' upper ends
COUNTS = (
    *("lc_eligible", "lc_weighed", "lc_allowed", "lc_started"),
    *("brake_eligible", "brake_started", "cut_in"),
)


def _unsafe_starts(before, after, p) -> jax.Array:
    """``()`` lane changes started on this step (``after.lc_time == 0``) whose new follower in
    ``before`` (the nearest body behind in the target lane, the ego included) would brake
    harder than ``b_safe`` behind the starter, or stand closer than ``s0``."""
    tr, eg = before.traffic, before.ego
    started = after.traffic.active & changing(after.traffic) & (after.traffic.lc_time == 0.0)
    to = after.traffic.lane  # (rows, slots)
    x, v, v0 = (a.reshape(-1) for a in (tr.x, tr.v, tr.v0))
    occ = jnp.concatenate([occupancy(tr, p).reshape(p.lanes, -1), ego_lanes(eg, p)[:, None]], 1)
    xs, vs, v0s = jnp.append(x, eg.x), jnp.append(v, eg.v), jnp.append(v0, eg.v0)
    n = x.size
    in_to = occ[to.reshape(-1)]  # (N, V): bodies in each starter's target lane
    behind = (
        in_to & (xs[None, :] <= x[:, None]) & (jnp.arange(n + 1)[None, :] != jnp.arange(n)[:, None])
    )
    back_x = jnp.max(jnp.where(behind, xs[None, :], -1e9), axis=1)
    has = back_x > -1e9
    f = jnp.argmax(jnp.where(behind, xs[None, :], -1e9), axis=1)
    gap = x - p.vehicle_length - back_x  # straight road: s is metres
    acc = idm_with_params(vs[f], v0s[f], gap, v, p)
    bad = has & ((acc < -p.b_safe - 1e-3) | (gap < p.idm_s0 - 1e-3))
    return jnp.sum(started.reshape(-1) & bad)


def make_run(env, p, n_envs: int, steps: int):
    """A jitted ``(obs, state, key) -> ((obs, state), totals)`` over ``steps`` steps."""
    length, width, road_w = p.vehicle_length, p.vehicle_width, p.lanes * p.lane_width

    def body(carry, key):
        obs, state = carry
        keys = jax.random.split(key, n_envs)
        step = jax.vmap(env.step, (0, 0, 0, None))
        obs, new, _, _, _, info = step(keys, state, scripted_action(obs, p), p)
        tr = new.traffic
        x, act = tr.x.reshape(n_envs, -1), tr.active.reshape(n_envs, -1)
        y = jax.vmap(vehicle_y, (0, None))(tr, p).reshape(n_envs, -1)
        pair = act[:, :, None] & act[:, None, :] & ~jnp.eye(x.shape[1], dtype=bool)
        overlap = pair & (jnp.abs(x[:, :, None] - x[:, None, :]) < length)
        overlap &= jnp.abs(y[:, :, None] - y[:, None, :]) < width
        out = {
            "overlaps": jnp.sum(overlap) // 2,
            "negative_speeds": jnp.sum(act & (tr.v.reshape(n_envs, -1) < 0.0)),
            "off_road": jnp.sum(act & ((y < 0.5 * width) | (y > road_w - 0.5 * width))),
            "unsafe_starts": jnp.sum(jax.vmap(_unsafe_starts, (0, 0, None))(state, new, p)),
            "vehicle_steps": jnp.sum(act),
            **{k: jnp.sum(info[k].astype(jnp.int32)) for k in COUNTS},
        }
        return (obs, new), out

    @jax.jit
    def run(obs, state, key):
        carry, out = jax.lax.scan(body, (obs, state), jax.random.split(key, steps))
        return carry, jax.tree.map(jnp.sum, out)

    return run


def check(
    n_envs: int, steps: int, overrides: tuple[str, ...] = HIGHEST, chunk: int = 500, seed: int = 0
) -> dict:
    """Run and return the totals with the two rates, their expectation and interval."""
    cfg = config.load(overrides=("env.mobil=true", "env.braking=true", *overrides))
    env, p = jaxlc.make(cfg)
    obs, state = jax.jit(jax.vmap(env.reset, (0, None)))(
        jax.random.split(jax.random.PRNGKey(seed), n_envs), p
    )
    chunk, chunks = min(chunk, steps), -(-steps // chunk)  # whole chunks, at least ``steps``
    run, totals = make_run(env, p, n_envs, chunk), Counter()
    for k in jax.random.split(jax.random.PRNGKey(seed + 1), chunks):
        (obs, state), out = run(obs, state, k)
        totals.update({name: int(value) for name, value in out.items()})
    rates = {
        "lane_change": ("lc_weighed", "lc_eligible", float(p.mobil_rate)),
        "braking": ("brake_started", "brake_eligible", float(p.braking_rate)),
    }
    for name, (k, n, rate) in rates.items():
        lo, hi = clopper_pearson(totals[k], totals[n], 0.999)
        totals[f"{name}_p"] = totals[k] / max(totals[n], 1)
        totals[f"{name}_expected"] = float(-np.expm1(-rate * float(p.dt)))
        totals[f"{name}_interval"] = (lo, hi)
    totals["env_steps"] = n_envs * chunk * chunks
    return totals


def main(argv: list[str] | None = None) -> dict:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--envs", type=int, default=256)
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--rates", choices=("highest", "default"), default="highest")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args(argv)
    t0 = time.perf_counter()
    out = check(args.envs, args.steps, HIGHEST if args.rates == "highest" else ())
    out["wall_s"] = time.perf_counter() - t0
    out["date"] = str(date.today())
    print(json.dumps(out, indent=1))
    if args.json:
        args.json.write_text(json.dumps(out, indent=1))
    return out


if __name__ == "__main__":
    main()
