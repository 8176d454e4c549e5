"""Time the pieces of one hazard-traffic env-step at 4,096 envs: each function jitted and
vmapped alone on a state warmed by 200 steps, median of 5 runs of 20 calls.

    python benchmarks/bench_traffic_pairs_cpu_2026-11-28/pieces.py   # this tree
    PYTHONPATH=<worktree of fc89e22> python .../pieces.py            # before
"""

import statistics
import time

import jax
import jax.numpy as jnp

import jaxlc
from jaxlc import config
from jaxlc.sim import leaders, mobil
from jaxlc.sim import traffic as T
from jaxlc.sim.road import ego_lanes, lane_scales, road_curvature
from jaxlc.sim.state import TrafficDraws
from jaxlc.study.machine import matmul_peak_gflops

N = 4096
env, p = jaxlc.make(config.load(overrides=["env.mobil=true", "env.braking=true"]))
_, st = jax.jit(jax.vmap(env.reset, (0, None)))(jax.random.split(jax.random.PRNGKey(0), N), p)


def body(s, k):
    return jax.vmap(env.step, (0, 0, 0, None))(jax.random.split(k, N), s, jnp.zeros((N, 1)), p)[
        1
    ], None


warm = jax.jit(lambda s, k: jax.lax.scan(body, s, jax.random.split(k, 200))[0])
st = jax.block_until_ready(warm(st, jax.random.PRNGKey(1)))
keys = jax.random.split(jax.random.PRNGKey(3), N)
ut = jax.jit(jax.vmap(lambda k: TrafficDraws.draw(k, p.lanes, p.slots_per_lane)))(keys)
around = lambda s: leaders.around(s.traffic, s.ego, p, lane_scales(road_curvature(s, p), p))  # noqa: E731
A = jax.jit(jax.vmap(around))(st)


def by_reduction(s):
    """Leads and lags as a masked min/max over a (lanes, V, V) pair axis, the same keys
    (written out, not ``leaders._keys``, so that the script also runs on fc89e22)."""
    tr, eg = s.traffic, s.ego
    x = jnp.append(tr.x.reshape(-1), eg.x)
    occ = jnp.concatenate(
        [leaders.occupancy(tr, p).reshape(p.lanes, -1), ego_lanes(eg, p)[:, None]], 1
    )
    bits = max(1, (x.shape[0] - 1).bit_length())
    q = jnp.floor((x + 0.5 * p.road_length) * (2 ** (31 - bits) / (2.0 * p.road_length)))
    key = jnp.clip(q, 0, 2 ** (31 - bits) - 1).astype(jnp.int32) * (1 << bits) + jnp.arange(
        x.shape[0]
    )
    ahead = key[None, :] > key[:, None]
    lead = jnp.min(jnp.where(occ[:, None, :] & ahead[None], key[None, None, :], 2**31 - 1), axis=2)
    behind = key[None, :] < key[:, None]
    lag = jnp.max(jnp.where(occ[:, None, :] & behind[None], key[None, None, :], -1), axis=2)
    return lead, lag


def timeit(name, f, *args, reps=20):
    g = jax.jit(jax.vmap(f))
    jax.block_until_ready(g(*args))
    ts = []
    for _ in range(5):
        t0 = time.perf_counter()
        for _ in range(reps):
            out = g(*args)
        jax.block_until_ready(out)
        ts.append((time.perf_counter() - t0) / reps)
    print(f"{name:34s} {statistics.median(ts) * 1e3:7.2f} ms per step", flush=True)


print(f"matmul peak {matmul_peak_gflops():.0f} GFLOP/s, {N} envs, jaxlc from {jaxlc.__file__}")
timeit("env.step (hazards)", lambda k, s: env.step(k, s, jnp.zeros(1), p)[1], keys, st)
timeit("leaders.around", around, st)
timeit("leads and lags by a pair-axis reduction", by_reduction, st)
timeit("traffic_accel, given around", lambda s, a: T.traffic_accel(s, p, a), st, A)
timeit("mobil.decide, given around", lambda s, a, u: mobil.decide(s.traffic, a, u, p), st, A, ut)
print(f"matmul peak {matmul_peak_gflops():.0f} GFLOP/s")
