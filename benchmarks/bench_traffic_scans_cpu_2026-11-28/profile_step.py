"""Where one env-step's time goes: XLA's CPU thunks of ``vmap(env.step)`` at 4,096 envs,
summed per source line of jaxlc that each thunk's HLO instruction came from.

    python benchmarks/bench_traffic_scans_cpu_2026-11-28/profile_step.py --traffic hazards

The step is jitted alone on a state warmed by 200 steps and profiled over 10 calls
(``jax.profiler.trace``, whose trace JAX writes itself); each thunk (a fusion, a scatter, a
loop) is attributed to the innermost stack frame XLA's optimized HLO records for its
instruction. A thunk split over the machine's threads counts once per part, so the column is
CPU time, not wall time. A loop (``while``) is a row apart, its wall time with its body's
thunks inside, and left out of the total, which holds the body's thunks already.
"""

from __future__ import annotations

import argparse
import collections
import glob
import gzip
import json
import re
import sys
import tempfile
from pathlib import Path

import jax
import jax.numpy as jnp

import jaxlc
from jaxlc import config

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "scripts"))
from sim_throughput import TRAFFIC  # noqa: E402  (the traffics by name, one definition)

CALLS = 10


def frames(hlo: str) -> dict[str, str]:
    """Each instruction's innermost source location, ``file:line function``."""
    lines = hlo.split("\n")
    names = ("FileNames", "FunctionNames", "FileLocations", "StackFrames")
    at = {name: lines.index(name) for name in names}

    def table(name: str, end: str) -> list[str]:
        return [x for x in lines[at[name] + 1 : at[end]] if x.strip()]

    files = {
        int(x.split()[0]): x.split()[1].strip('"').split("/")[-1]
        for x in table("FileNames", "FunctionNames")
    }
    funcs = {
        int(x.split()[0]): x.split()[1].strip('"') for x in table("FunctionNames", "FileLocations")
    }
    locs = {}
    for x in table("FileLocations", "StackFrames"):
        m = re.match(r"(\d+) \{file_name_id=(\d+) function_name_id=(\d+) line=(\d+)", x)
        locs[int(m[1])] = f"{files[int(m[2])]}:{m[4]} {funcs[int(m[3])]}"
    frame = {}
    for x in lines[at["StackFrames"] + 1 :]:
        m = re.match(r"(\d+) \{file_location_id=(\d+)", x)
        if m:
            frame[int(m[1])] = locs[int(m[2])]
    where = {}
    for x in lines:
        m = re.match(r"\s+(?:ROOT )?%(\S+) = .*?stack_frame_id=(\d+)", x)
        if m:
            where.setdefault(m[1], frame[int(m[2])])
    return where


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--traffic", choices=sorted(TRAFFIC), default="hazards")
    ap.add_argument("--envs", type=int, default=4096)
    ap.add_argument("--top", type=int, default=30)
    args = ap.parse_args(argv)
    env, p = jaxlc.make(config.load(overrides=list(TRAFFIC[args.traffic])))
    n = args.envs
    keys = jax.random.split(jax.random.PRNGKey(0), n)
    _, st = jax.jit(jax.vmap(env.reset, (0, None)))(keys, p)

    def body(s, k):
        ks = jax.random.split(k, n)
        return jax.vmap(env.step, (0, 0, 0, None))(ks, s, jnp.zeros((n, 1)), p)[1], None

    warm = jax.jit(lambda s, k: jax.lax.scan(body, s, jax.random.split(k, 200))[0])
    st = jax.block_until_ready(warm(st, jax.random.PRNGKey(1)))
    step = jax.jit(jax.vmap(lambda k, s: env.step(k, s, jnp.zeros(1), p)[1]))
    keys = jax.random.split(jax.random.PRNGKey(3), n)
    where = frames(step.lower(keys, st).compile().as_text())
    jax.block_until_ready(step(keys, st))
    with tempfile.TemporaryDirectory() as tmp:
        with jax.profiler.trace(tmp):
            for _ in range(CALLS):
                out = step(keys, st)
            jax.block_until_ready(out)
        (path,) = glob.glob(f"{tmp}/plugins/profile/*/*.trace.json.gz")
        events = [e for e in json.load(gzip.open(path))["traceEvents"] if e.get("ph") == "X"]
    ms = collections.defaultdict(float)
    for e in events:
        name = e["name"]
        if name.startswith("while"):
            ms[where.get(name, "?") + " (loop: wall, body included)"] += e["dur"] / CALLS / 1e3
        elif name in where or name.startswith(("wrapped_", "copy", "fusion")):
            ms[where.get(name, "(no source line)")] += e["dur"] / CALLS / 1e3
    total = sum(t for loc, t in ms.items() if not loc.endswith(")"))
    print(f"{args.traffic}, {n} envs: {total:.2f} ms of thunks per step (CPU, all threads)")
    for loc, t in sorted(ms.items(), key=lambda kv: -kv[1])[: args.top]:
        print(f"{t:7.3f} ms {100 * t / total:5.1f}%  {loc}")


if __name__ == "__main__":
    main()
