"""Throughput of the vmapped DDPG update against this machine's float32 matmul peak, measured
in one run so that all figures see the same machine state:

- ``peak_gflops``: a jitted ``(n, n) @ (n, n)`` float32 product (``matmul_call``);
- ``grid_updates_per_s``: ``--models`` models' sample + ``ddpg.update`` steps, vmapped, in one
  ``lax.scan`` (``grid_update_call``); ``achieved_gflops`` counts only their matrix products
  (``update_products``), so ``share_of_peak`` is below 1 by the elementwise work, Adam and the
  sampling gather;
- where one grid update's time goes (one device): its products alone at their shapes
  (``kernels_call``: their share of the peak bounds the update's with these kernels), its
  Adam + soft-target pass alone (``optimizer_call``), the rest (negative when the parts
  overlap), beside a plain streamed ``a + 1e-3 b`` over the Adam pass's memory (``stream_call``);
  ``share_ceiling`` is the share of an update made of its products at their speed alone and an
  Adam pass moving its minimum 36 bytes per parameter at the streamed bandwidth.

Each figure is the median of ``--repeats`` calls after a compiling one, the calls of all
alternating so that all see the same load from other processes (``share_of_peak_best_of``
takes the fastest of each; the 1-minute load average is recorded). ``XLA_FLAGS`` applies.

Usage: ``python -m benchmarks.update_throughput [--models 9 --batch 64 --repeats 5]``;
``--devices N`` lays the models over N devices (on a CPU, N host devices it asks XLA for
unless ``XLA_FLAGS`` sets their number); ``--tiny`` shrinks everything for tests. Writes
``benchmarks/results/update_throughput.csv``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import statistics
import time
from collections.abc import Callable, Sequence
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from benchmarks import RESULTS, write_csv
from jaxlc.config import DDPGConfig
from jaxlc.learn import ddpg, replay
from jaxlc.sim.env import OBS_DIM
from jaxlc.sim.observation import MIRROR_SIGNS
from jaxlc.study import machine


def update_products(
    obs_dim: int,
    hidden: Sequence[int],
    batch: int,
    act_dim: int = 1,
    symmetric: bool = False,
    pairs: bool = False,
) -> list[tuple[int, int, int]]:
    """The matrix products ``(m, k, n)`` (an ``(m, k) @ (k, n)``) of one ``ddpg.update`` of
    one model.

    A dense layer ``in -> out`` on ``batch`` rows is ``(batch, in, out)`` forward; its backward
    is ``(in, batch, out)`` for the weight gradient and ``(batch, out, in)`` for the input
    gradient. Counted:

    - target actor on s' and target critic on (s', mu'(s')): one forward each;
    - critic on (s, a): forward, weight gradients of every layer, input gradients of every
      layer but the first (the input is data);
    - actor on s, critic on (s, mu(s)): forward each; input gradients through every critic
      layer (the first only for the action columns) and every actor layer but the first;
      weight gradients of every actor layer.

    A symmetric actor (``ddpg.symmetric_actor``) runs its trunk twice, on s and on Ms: every
    actor product above counts twice; on a paired batch (``ddpg.mirror_pairs``, ``pairs``)
    Ms is a row of the batch already and ``Actor.paired`` runs it once.
    """
    actor = list(zip((obs_dim, *hidden), (*hidden, act_dim), strict=True))
    critic = list(zip((obs_dim + act_dim, *hidden), (*hidden, 1), strict=True))

    def fwd(layers: list[tuple[int, int]]) -> list[tuple[int, int, int]]:
        return [(batch, i, o) for i, o in layers]

    def wgrad(layers: list[tuple[int, int]]) -> list[tuple[int, int, int]]:
        return [(i, batch, o) for i, o in layers]

    def igrad(layers: list[tuple[int, int]]) -> list[tuple[int, int, int]]:
        return [(batch, o, i) for i, o in layers]

    trunks = 2 if symmetric and not pairs else 1
    target = fwd(actor) * trunks + fwd(critic)
    critic_step = fwd(critic) + wgrad(critic) + igrad(critic[1:])
    actor_step = (
        fwd(actor) * trunks
        + fwd(critic)
        + igrad(critic[1:])
        + [(batch, hidden[0], act_dim)]  # the first critic layer's action columns
        + (wgrad(actor) + igrad(actor[1:])) * trunks
    )
    return target + critic_step + actor_step


def matmul_flops(products: Sequence[tuple[int, int, int]]) -> int:
    """Matmul FLOPs of ``update_products``' list: 2 per multiply-add."""
    return sum(2 * m * k * n for m, k, n in products)


def _timed(fn: Callable[[], object]) -> Callable[[], float]:
    """Compile and warm ``fn`` up; return a function that times one call in seconds."""
    jax.block_until_ready(fn())

    def once() -> float:
        t0 = time.perf_counter()
        jax.block_until_ready(fn())
        return time.perf_counter() - t0

    return once


def matmul_call(n: int) -> Callable[[], jax.Array]:
    """A jitted float32 ``(n, n) @ (n, n)``: ``2 n^3`` FLOPs per call."""
    ka, kb = jax.random.split(jax.random.key(0))
    a = jax.random.normal(ka, (n, n), jnp.float32)
    b = jax.random.normal(kb, (n, n), jnp.float32)
    dot = jax.jit(jnp.dot)
    return lambda: dot(a, b)


def _scanned(body: Callable, carry: object, steps: int, *consts: object) -> Callable[[], object]:
    """``steps`` iterations of ``carry = body(carry, *consts)`` in one jitted ``lax.scan``:
    buffers are updated in place, as in the grid update's scan, and a call costs one dispatch.
    ``consts`` are arguments, not captured: at 900 models they are gigabytes, which a closure
    would bake into the program as constants (compiling for minutes)."""
    run = jax.jit(lambda c, *k: jax.lax.scan(lambda c, _: (body(c, *k), None), c, None, steps)[0])
    return lambda: run(carry, *consts)


def stream_call(n: int, steps: int) -> Callable[[], object]:
    """``a <- a + 1e-3 b`` over two ``(n,)`` float32 arrays, ``steps`` times: each step reads
    ``8 n`` bytes and writes ``4 n``, the memory bandwidth that an elementwise pass sees."""
    ka, kb = jax.random.split(jax.random.key(5))
    b = jax.random.normal(kb, (n,))
    return _scanned(lambda a, b: a + 1e-3 * b, jax.random.normal(ka, (n,)), steps, b)


def kernels_call(
    products: Sequence[tuple[int, int, int]], models: int, steps: int
) -> Callable[[], object]:
    """Every product of ``products`` alone, batched over ``models`` as the vmapped update
    batches it (``(models, m, k) @ (models, k, n)``), ``steps`` times in a chain: the time XLA's
    matmul kernels need for one grid update's FLOPs with nothing else around them.

    Each step adds a 1e-30 multiple of one element of every product to one element of every
    left operand, so that no product can be hoisted out of the loop or dropped, at the cost of
    a few scalar operations."""
    keys = jax.random.split(jax.random.key(3), len(products))
    ab = [
        (jax.random.normal(ka, (models, m, k)), jax.random.normal(kb, (models, k, n)))
        for (m, k, n), (ka, kb) in zip(products, map(jax.random.split, keys), strict=True)
    ]

    def body(left: list[jax.Array], right: list[jax.Array]) -> list[jax.Array]:
        out = [jnp.einsum("bmk,bkn->bmn", a, b) for a, b in zip(left, right, strict=True)]
        tick = 1e-30 * sum(o[:, 0, 0] for o in out)  # (models,)
        return [a.at[:, 0, 0].add(tick) for a in left]

    return _scanned(body, [a for a, _ in ab], steps, [b for _, b in ab])


def _learners(cfg: DDPGConfig, models: int, key: jax.Array) -> ddpg.Learner:
    """``models`` fresh learners stacked on a leading axis (jitted: eager init is slow)."""
    init = jax.jit(jax.vmap(lambda k: ddpg.init_learner(k, OBS_DIM, cfg)))
    return init(jax.random.split(key, models))


def optimizer_call(cfg: DDPGConfig, models: int, steps: int) -> Callable[[], object]:
    """``ddpg.apply_gradients`` (Adam and the soft target update) of the actor and the critic
    of ``models`` models, vmapped, with fixed gradients, ``steps`` times: the update's
    elementwise pass over every parameter, alone. It moves at least 36 bytes per parameter:
    params, gradient, both Adam moments and the target read, and all but the gradient
    written."""
    lrn = _learners(cfg, models, jax.random.key(4))
    grads = jax.tree.map(lambda x: jnp.full_like(x, 1e-3), (lrn.critic, lrn.actor))
    hyper = ddpg.Hyper.from_config(cfg)

    def many(lrn: ddpg.Learner, grads: tuple[ddpg.Params, ddpg.Params]) -> ddpg.Learner:
        return jax.vmap(lambda one, g: ddpg.apply_gradients(one, *g, hyper, cfg.tau))(lrn, grads)

    return _scanned(many, lrn, steps, grads)


def grid_update_call(
    cfg: DDPGConfig, models: int, memories: Sequence[int], updates: int, devices: int = 1
) -> Callable[[], object]:
    """``updates`` vmapped sample + update steps of ``models`` models in one ``lax.scan``;
    with ``devices > 1`` the models are laid over that many devices (``shard_map``, as the
    sweep's ``--devices`` does; ``models`` must be a multiple of ``devices``)."""
    cap_max = max(memories)
    caps = jnp.asarray([memories[i % len(memories)] for i in range(models)], jnp.int32)
    k_init, k_run = jax.random.split(jax.random.key(1))
    learners = _learners(cfg, models, k_init)
    hyper = jax.vmap(lambda _: ddpg.Hyper.from_config(cfg))(jnp.arange(models))

    # host-side random transitions: one compiled vmapped add, called until the largest is full
    rng = np.random.default_rng(2)
    n = min(memories)  # rows per add: add() needs n <= every capacity
    add = jax.jit(jax.vmap(replay.add))
    memory = jax.vmap(lambda c: replay.init(cap_max, OBS_DIM, 1, c))(caps)
    for _ in range(-(-cap_max // n)):
        obs, next_obs = rng.normal(size=(2, models, n, OBS_DIM)).astype(np.float32)
        action = rng.uniform(-1, 1, (models, n, 1)).astype(np.float32)
        reward = rng.normal(size=(models, n)).astype(np.float32)
        done = np.zeros((models, n), np.float32)
        memory = add(memory, obs, action, reward, next_obs, done, np.ones((models, n), bool))

    mirror = MIRROR_SIGNS if cfg.mirror else None

    def one(learner: ddpg.Learner, mem: replay.Replay, h: ddpg.Hyper, key: jax.Array):
        batch = replay.sample(mem, key, cfg.batch_size, mirror, None, cfg.mirror_pairs)
        return ddpg.update(learner, batch, h, cfg)

    def scan(learners: ddpg.Learner, memory: replay.Replay, hyper: ddpg.Hyper, keys: jax.Array):
        def body(carry: ddpg.Learner, k: jax.Array) -> tuple[ddpg.Learner, jax.Array]:
            new, metrics = jax.vmap(one)(carry, memory, hyper, k)
            return new, metrics["critic_loss"]

        return jax.lax.scan(body, learners, keys)

    if devices > 1:
        mesh = Mesh(np.asarray(jax.devices()[:devices]), ("models",))
        specs = (P("models"), P("models"), P("models"), P(None, "models"))
        scan = jax.shard_map(
            scan, mesh=mesh, in_specs=specs, out_specs=(P("models"), P(None, "models"))
        )
    keys = jax.vmap(lambda k: jax.random.split(k, models))(jax.random.split(k_run, updates))
    run = jax.jit(scan)
    return lambda: run(learners, memory, hyper, keys)


def _parse(argv: Sequence[str] | None) -> argparse.Namespace:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--models", type=int, default=9)
    p.add_argument("--batch", type=int, default=64)
    p.add_argument("--hidden", type=int, nargs="+", default=[300, 600])
    p.add_argument("--memories", type=int, nargs="+", default=[2000, 4000, 8000])
    p.add_argument("--updates", type=int, default=200, help="updates per timed scan")
    p.add_argument("--repeats", type=int, default=5)
    p.add_argument("--matmul-n", type=int, default=2048)
    p.add_argument("--stream-n", type=int, default=0, help="floats streamed (0: as Adam)")
    p.add_argument("--out", type=Path, default=RESULTS / "update_throughput.csv")
    p.add_argument("--devices", type=int, default=1, help="devices the models are laid over")
    p.add_argument("--tiny", action="store_true", help="small sizes, for tests")
    args = p.parse_args(argv)
    if args.tiny:
        args.models, args.batch, args.hidden, args.memories = 3, 8, [16, 32], [64, 96, 128]
        args.updates, args.repeats, args.matmul_n, args.stream_n = 5, 2, 128, 1 << 12
    machine.use_host_devices(args.devices)  # on a CPU, as many host devices (before JAX starts)
    if args.devices > len(jax.devices()) or args.models % args.devices:
        p.error(f"--devices {args.devices} must divide --models and be at most {jax.devices()}")
    return args


def main(argv: Sequence[str] | None = None) -> dict[str, float]:
    """Measure, write the CSV row, print it; return the figures unrounded."""
    args = _parse(argv)
    cfg = dataclasses.replace(DDPGConfig(), hidden=tuple(args.hidden), batch_size=args.batch)
    products = update_products(OBS_DIM, cfg.hidden, cfg.batch_size, 1, cfg.symmetric_actor)
    shapes = jax.eval_shape(lambda k: ddpg.init_learner(k, OBS_DIM, cfg), jax.random.key(0))
    params = args.models * sum(x.size for x in jax.tree.leaves((shapes.actor, shapes.critic)))
    stream_n = args.stream_n or int(4.5 * params)  # two arrays of 36 bytes per parameter
    timers = {
        "dot": _timed(matmul_call(args.matmul_n)),
        "grid": _timed(
            grid_update_call(cfg, args.models, args.memories, args.updates, args.devices)
        ),
        "kernels": _timed(kernels_call(products, args.models, args.updates)),
        "optimizer": _timed(optimizer_call(cfg, args.models, args.updates)),
        "stream": _timed(stream_call(stream_n, args.updates)),
    }
    times: dict[str, list[float]] = {k: [] for k in timers}
    for _ in range(args.repeats):  # alternate, so all see the same load from other processes
        for k, once in timers.items():
            times[k].append(once())
    med = {k: statistics.median(v) for k, v in times.items()}
    best = {k: min(v) for k, v in times.items()}  # the fastest calls (a shared machine)
    dot_gflop, flops = 2 * args.matmul_n**3 / 1e9, matmul_flops(products)
    peak, rate = dot_gflop / med["dot"], args.updates / med["grid"]
    work = args.models * flops / 1e9  # GFLOP of matrix products in one grid update
    # one grid update's time, ms, in parts (module docstring)
    kernels_ms = 1e3 * med["kernels"] / args.updates
    optimizer_ms = 1e3 * med["optimizer"] / args.updates
    stream_gbps = 12 * stream_n * args.updates / med["stream"] / 1e9
    # an update of its products at their speed alone and Adam's 36 bytes/param streamed
    floor_ms = kernels_ms + 36 * params / stream_gbps / 1e6
    figures = {
        "peak_gflops": peak,
        "grid_updates_per_s": rate,
        "mflop_per_model_update": flops / 1e6,
        "achieved_gflops": rate * work,
        "share_of_peak": rate * work / peak,
        "share_of_peak_best_of": args.updates / best["grid"] * work / (dot_gflop / best["dot"]),
        "update_ms": 1e3 / rate,
        "products_alone_ms": kernels_ms,
        "products_alone_share_of_peak": work / (kernels_ms / 1e3) / peak,
        "optimizer_alone_ms": optimizer_ms,
        "optimizer_alone_gbps": 36 * params / (optimizer_ms / 1e3) / 1e9,
        "stream_gbps": stream_gbps,
        "share_ceiling": work / (floor_ms / 1e3) / peak,
        "rest_ms": 1e3 / rate - kernels_ms - optimizer_ms,
    }
    row = {
        "backend": jax.default_backend(),
        "models": args.models,
        "devices": args.devices,
        "batch": args.batch,
        "hidden": "x".join(map(str, args.hidden)),
        "memories": "/".join(map(str, args.memories)),
        "updates_per_scan": args.updates,
        "repeats": args.repeats,
        "matmul_n": args.matmul_n,
        **{k: round(v, 4 if "share" in k else 3) for k, v in figures.items()},
        "loadavg_1min": round(os.getloadavg()[0], 2),
    }
    write_csv(args.out, [row])
    width = max(map(len, row))
    for k, v in row.items():
        print(f"{k:<{width}}  {v}")
    print(f"wrote {args.out}")
    return figures


if __name__ == "__main__":
    main()
