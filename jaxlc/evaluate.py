"""``python -m jaxlc.evaluate RUN_DIR``: run saved checkpoints on fixed lane-change cases.

    python -m jaxlc.evaluate runs/smoke                        # default checkpoints, 100 cases
    python -m jaxlc.evaluate runs/paper --episodes 100,5000 --model 3
    python -m jaxlc.evaluate --checkpoint runs/paper/checkpoints/m03_s0/ep05000.msgpack

A *case* is one lane-change scenario: ``env.reset`` from a fixed key, then steps until the
first episode of that env ends (any reason, no_gap included) or ``max_steps`` pass. Every
policy (each checkpoint, and the scripted controller as a baseline row) sees the same cases,
with no exploration noise.

Until the gap is accepted the action is ignored (the ego keeps its lane), so the run up to
the RL phase is the same for every policy: ``programs`` gives ``start_cases``, which
simulates it once per case, and ``rollout``, which broadcasts those states to all policies
and runs them in one jitted program, vmapped over policies and cases, with a ``while_loop``
over time. Step keys are ``fold_in(case key, env time)``, so the split changes no random
draw. "Left" is toward higher y (lane index up; y points left of the driving direction).

Outcome buckets are the reason codes of ``jaxlc.reward`` with 0 read as "unfinished" (hit
the step cap), so every case lands in exactly one bucket. Writes ``RUN_DIR/eval/eval.json``,
``eval.csv``, ``cases.npz`` (per policy and case) and ``traces.npz`` (the few drawn cases),
the statistics over seeds (``jaxlc.stats``: ``cells.json``, ``cells.csv``,
``improvement.csv``), then the figures and ``RUN_DIR/report.md`` (skip figures with
``--no-figures``).

    python -m jaxlc.evaluate --compare RUN_A RUN_B [--out DIR]

compares two runs that are already evaluated (their ``eval/eval.json``; nothing is
re-evaluated): per cell and checkpoint, B - A of the mean success rate with a bootstrap
interval, into ``DIR`` (default ``RUN_B/compare_<name of RUN_A>/``): ``compare.md``,
``compare.csv``, ``compare.png``, over the checkpoint episodes both runs evaluated. Runs
whose cells differ, or that share no checkpoint episode, are refused (exit status 2).
"""

from __future__ import annotations

import argparse
import csv
import functools
import io
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxlc import checkpoint, config, machine, stats, tree
from jaxlc.checkpoint import CheckpointError
from jaxlc.controller import scripted_action
from jaxlc.env import ACT_DIM, OBS_DIM, RL, EnvParams, EnvState, LaneChangeEnv, observation
from jaxlc.networks import make_networks
from jaxlc.reward import REASONS
from jaxlc.stats import CELL_AXES, StatsError, final_rows
from jaxlc.train import check_devices

OUTCOMES = ("unfinished",) + REASONS[1:]  # index = reason code; 0: hit the step cap
MEASURES = (
    "success_rate",
    "avg_return",
    "duration_s",
    "peak_lat_acc",
    "peak_yaw_rate",
    "overshoot_m",
    "r_s",
    "r_e",
    "r_d",
    "timeout_offset_m",
    "timeout_heading",
    "timeout_yaw_rate",
)
EVAL_FIELDS = (
    ("label", "model", "cell", "seed", "k", "memory", "episode", "cases", "performed")
    + OUTCOMES
    + MEASURES
)


class EvalError(Exception):
    """The evaluation cannot run; the message names the problem and the fix."""


@flax.struct.dataclass
class Policies:
    """Rows to evaluate; every leaf has a leading ``(policies,)`` axis."""

    actor: Any  # actor params pytree
    k: Array  # (policies,) int32 action-update step
    scripted: Array  # (policies,) bool: act with controller.scripted_action, not the actor


@flax.struct.dataclass
class Cases:
    """Every case at the moment its RL phase begins (or its episode ended without one)."""

    state: EnvState  # (cases, ...)
    obs: Array  # (cases, OBS_DIM)
    key: Array  # (cases, 2) key that step keys are folded from
    reason: Array  # (cases,) int32: end before the RL phase (no_gap, collision), else 0
    performed: Array  # (cases,) bool: reached the RL phase
    side: Array  # (cases,) int32: +1 toward higher y (left), -1 right, 0 no lane change


@flax.struct.dataclass
class Outcome:
    """Per policy and case ``(policies, cases)``; dynamics are over the RL steps."""

    reason: Array  # int32 outcome index (OUTCOMES)
    performed: Array  # bool
    ret: Array  # total return
    r_s: Array
    r_e: Array
    r_d: Array
    steps: Array  # int32 RL steps of the manoeuvre
    peak_lat_acc: Array  # max |v * omega|, m/s^2
    peak_yaw_rate: Array  # max |omega|, rad/s
    overshoot: Array  # max distance past the target centre line, m (0 if none)
    # The ego at the manoeuvre's last step (NaN without one), so a timeout's cause shows:
    # short of the lane (offset < 0), swinging (large omega) or just outside the success box.
    final_offset: Array  # signed offset to the target centre line toward the target side, m
    final_psi: Array  # heading, rad
    final_omega: Array  # yaw rate, rad/s


@flax.struct.dataclass
class Trace:
    """The drawn cases, frame 0 = start of the RL phase: ``(policies, traced, frames, ...)``."""

    x: Array  # ego front bumper, m
    y: Array  # ego centre line, m
    psi: Array
    frames: Array  # (policies, traced) int32 valid frames
    traffic_x: Array  # (..., lanes, slots)
    traffic_active: Array  # (..., lanes, slots) bool
    lead_x: Array  # target-lane lead vehicle (front bumper), valid where has_lead
    lag_x: Array
    has_lead: Array
    has_lag: Array


def case_keys(seed: int, cases: int) -> Array:
    """``(cases, 2)`` keys; case ``i`` is the same for any ``cases >= i + 1``."""
    root = jax.random.PRNGKey(seed)
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(jnp.arange(cases))


def default_episodes(every: int, final: int) -> list[int]:
    """The paper's checkpoint choice (100, 400, 800, ..., 4800, 5000 for every=100, 5000
    episodes) for any spacing: the first, every 4th, and the last."""
    return sorted({every, *range(4 * every, final + 1, 4 * every), final})


@functools.lru_cache(maxsize=8)
def programs(cfg: config.Config, max_steps: int, devices: int = 1) -> tuple[Any, Any]:
    """Jitted ``start_cases(keys) -> Cases`` and ``rollout(policies, cases, traced) ->
    (Outcome, Trace)`` for a config (cached: configs are frozen and hashable).

    With ``devices > 1`` the policies axis is laid over a 1-D mesh of the first ``devices``
    devices (``shard_map``, as the sweep lays its models): each device rolls out its block of
    policies on every case; the policy count must be a multiple of ``devices``."""
    env = LaneChangeEnv()
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    actor_net, _ = make_networks(cfg.ddpg, ACT_DIM)
    origin = base.lanes // 2
    limit = int(round(base.manoeuvre_time_limit / base.dt))  # RL steps before a timeout
    zero = jnp.zeros(ACT_DIM)

    def start_case(key: Array) -> Cases:
        k_reset, k_run = jax.random.split(key)
        _, state = env.reset(k_reset, base)

        def going(c: tuple[EnvState, Array]) -> Array:
            s, reason = c
            return (reason == 0) & (s.ego.phase != RL) & (s.time < max_steps)

        def step(c: tuple[EnvState, Array]) -> tuple[EnvState, Array]:
            s, _ = c
            *_, s, _, _, _, info = env.step(jax.random.fold_in(k_run, s.time), s, zero, base)
            return s, info["reason"]

        state, reason = jax.lax.while_loop(going, step, (state, jnp.int32(0)))
        performed = (reason == 0) & (state.ego.phase == RL)
        side = jnp.where(performed, state.ego.target - origin, 0).astype(jnp.int32)
        return Cases(state, observation(state, base), k_run, reason, performed, side)

    def rollout(pol: Policies, cs: Cases, traced: Array) -> tuple[Outcome, Trace]:
        n_pol, n_case = pol.k.shape[0], cs.reason.shape[0]
        pc = (n_pol, n_case)
        bcast = functools.partial(jax.tree.map, lambda a: jnp.broadcast_to(a, (n_pol,) + a.shape))
        state, obs = bcast(cs.state), bcast(cs.obs)
        f0, i0 = jnp.zeros(pc, jnp.float32), jnp.zeros(pc, jnp.int32)
        out = Outcome(
            reason=bcast(cs.reason),
            performed=bcast(cs.performed),
            ret=f0,
            r_s=f0,
            r_e=f0,
            r_d=f0,
            steps=i0,
            peak_lat_acc=f0,
            peak_yaw_rate=f0,
            overshoot=jnp.full(pc, -jnp.inf),
            final_offset=jnp.full(pc, jnp.nan),
            final_psi=jnp.full(pc, jnp.nan),
            final_omega=jnp.full(pc, jnp.nan),
        )
        trace = _empty_trace(n_pol, traced.shape[0], limit + 2, base)
        trace = _record(trace, 0, state, traced, jnp.ones((n_pol, traced.shape[0]), bool))
        side = bcast(cs.side).astype(jnp.float32)

        def step_policy(k: Array, keys: Array, s: EnvState, a: Array) -> tuple:
            return jax.vmap(env.step, (0, 0, 0, None))(keys, s, a, base.replace(k=k))

        def body(c: tuple) -> tuple:
            i, state, obs, done, out, trace = c
            mu = jax.vmap(actor_net.apply)(pol.actor, obs)  # (policies, cases, 1)
            action = jnp.where(pol.scripted[:, None, None], scripted_action(obs, base), mu)
            keys = jax.vmap(jax.vmap(jax.random.fold_in))(bcast(cs.key), state.time)
            new_obs, new, r, _, _, info = jax.vmap(step_policy)(pol.k, keys, state, action)
            live = ~done  # (policies, cases); only live cases are in the RL phase
            lat = jnp.abs(new.ego.v * new.ego.omega)

            def add(acc: Array, value: Array) -> Array:
                return acc + jnp.where(live, value, 0.0)

            def peak(acc: Array, value: Array) -> Array:
                return jnp.maximum(acc, jnp.where(live, value, acc))

            def last(acc: Array, value: Array) -> Array:
                return jnp.where(live, value, acc)

            out = out.replace(
                reason=jnp.where(live, info["reason"], out.reason),
                ret=add(out.ret, r),
                r_s=add(out.r_s, info["r_s"]),
                r_e=add(out.r_e, info["r_e"]),
                r_d=add(out.r_d, info["r_d"]),
                steps=jnp.where(live, info["episode_steps"], out.steps),
                peak_lat_acc=peak(out.peak_lat_acc, lat),
                peak_yaw_rate=peak(out.peak_yaw_rate, jnp.abs(new.ego.omega)),
                overshoot=peak(out.overshoot, info["offset"] * side),
                final_offset=last(out.final_offset, info["offset"] * side),
                final_psi=last(out.final_psi, new.ego.psi),
                final_omega=last(out.final_omega, new.ego.omega),
            )
            ended = info["reason"] != 0
            done = done | (live & (ended | (new.time >= max_steps)))
            # Finished cases freeze, so their last frame is where the manoeuvre ended.
            state, obs = tree.where(live, (new, new_obs), (state, obs))
            trace = _record(trace, i + 1, state, traced, live[:, traced])
            return i + 1, state, obs, done, out, trace

        def going(c: tuple) -> Array:
            i, _, _, done, _, _ = c
            return (i <= limit) & jnp.any(~done)

        init = (jnp.int32(0), state, obs, ~bcast(cs.performed), out, trace)
        *_, out, trace = jax.lax.while_loop(going, body, init)
        # A case still running here hit the cap: its reason stays 0, "unfinished".
        return out.replace(overshoot=jnp.maximum(out.overshoot, 0.0)), trace

    if devices > 1:
        mesh = Mesh(np.asarray(jax.devices()[:devices]), ("models",))
        rollout = jax.shard_map(
            rollout,
            mesh=mesh,
            in_specs=(P("models"), P(), P()),
            out_specs=P("models"),
            check_vma=False,  # per-policy work only, no collectives to check
        )
    return jax.jit(jax.vmap(start_case)), jax.jit(rollout)


def _empty_trace(n_pol: int, n_traced: int, frames: int, p: EnvParams) -> Trace:
    shape = (n_pol, n_traced, frames)
    lanes = shape + (p.lanes, p.slots_per_lane)
    f, b = jnp.zeros(shape, jnp.float32), jnp.zeros(shape, bool)
    return Trace(
        x=f,
        y=f,
        psi=f,
        frames=jnp.zeros(shape[:2], jnp.int32),
        traffic_x=jnp.zeros(lanes, jnp.float32),
        traffic_active=jnp.zeros(lanes, bool),
        lead_x=f,
        lag_x=f,
        has_lead=b,
        has_lag=b,
    )


def _record(trace: Trace, i: Array | int, state: EnvState, traced: Array, live: Array) -> Trace:
    """Write frame ``i`` of the traced cases (``live``: ``(policies, traced)``, counts it)."""
    eg, tr, nb = state.ego, state.traffic, state.nb
    values = {
        "x": eg.x,
        "y": eg.y,
        "psi": eg.psi,
        "traffic_x": tr.x,
        "traffic_active": tr.active,
        "lead_x": nb.a1_x,
        "lag_x": nb.b1_x,
        "has_lead": nb.has_a1,
        "has_lag": nb.has_b1,
    }
    new = {k: getattr(trace, k).at[:, :, i].set(v[:, traced]) for k, v in values.items()}
    return trace.replace(**new, frames=trace.frames + live.astype(jnp.int32))


def pick_traced(cases: Cases, n: int) -> np.ndarray:
    """Up to ``n`` performed cases to draw, alternating left and right lane changes."""
    side, performed = np.asarray(cases.side), np.asarray(cases.performed)
    left = list(np.nonzero(performed & (side > 0))[0])
    right = list(np.nonzero(performed & (side < 0))[0])
    picked: list[int] = []
    while len(picked) < n and (left or right):
        for group in (left, right):
            if group and len(picked) < n:
                picked.append(int(group.pop(0)))
    return np.asarray(picked or [0], np.int32)  # one case at least keeps shapes non-empty


def init_actor(cfg: config.Config, key: Array | None = None) -> Any:
    """Fresh actor params for ``cfg`` (a "random-params" baseline, and a shape template)."""
    actor_net, _ = make_networks(cfg.ddpg, ACT_DIM)
    key = jax.random.PRNGKey(0) if key is None else key
    return actor_net.init(key, jnp.zeros((1, OBS_DIM), jnp.float32))


def evaluate_policies(
    cfg: config.Config,
    actors: Sequence[Any | None],
    ks: Sequence[int],
    *,
    cases: int = 100,
    seed: int = 0,
    max_steps: int = 1500,
    chunk: int = 32,
    traced: int = 4,
    devices: int = 1,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Evaluate actors (``None``: the scripted controller) with action-update steps ``ks``.

    Returns numpy dicts ``(outcome (policies, cases), trace (policies, traced, ...),
    case info (cases,))``. Policies run in chunks of ``chunk`` (the last padded to full size,
    so one compiled program serves all) to bound memory; a chunk is a multiple of ``devices``,
    over which its policies are laid.
    """
    check_devices(devices, EvalError)
    start, rollout = programs(cfg, max_steps, devices)
    cs = start(case_keys(seed, cases))
    idx = pick_traced(cs, traced)
    template = jax.tree.map(np.zeros_like, init_actor(cfg))
    rows = [
        (a if a is not None else template, int(k), a is None)
        for a, k in zip(actors, ks, strict=True)
    ]
    size = -(-min(chunk, len(rows)) // devices) * devices
    outs, traces = [], []
    for lo in range(0, len(rows), size):
        part = rows[lo : lo + size]
        part = part + [part[-1]] * (size - len(part))
        pol = Policies(
            actor=jax.tree.map(
                lambda *xs: jnp.stack([jnp.asarray(x) for x in xs]), *[r[0] for r in part]
            ),
            k=jnp.asarray([r[1] for r in part], jnp.int32),
            scripted=jnp.asarray([r[2] for r in part]),
        )
        out, trace = jax.device_get(rollout(pol, cs, jnp.asarray(idx)))
        n = min(size, len(rows) - lo)
        outs.append(jax.tree.map(lambda a, n=n: a[:n], out))
        traces.append(jax.tree.map(lambda a, n=n: a[:n], trace))
    info = {
        "case": np.arange(cases),
        "performed": np.asarray(cs.performed),
        "side": np.asarray(cs.side),
        "traced": idx,
    }
    return _concat(outs), _concat(traces), info


def _concat(parts: list[Any]) -> dict[str, np.ndarray]:
    """Chunks of an ``Outcome``/``Trace`` -> one dict of arrays along the policy axis."""
    return {k: np.concatenate([vars(x)[k] for x in parts]) for k in vars(parts[0])}


def _defined(v: Any) -> bool:
    return v is not None and v == v


def _mean(values: np.ndarray) -> float:
    return float(np.mean(values)) if values.size else math.nan


def _median_abs(values: np.ndarray) -> float:
    return float(np.median(np.abs(values))) if values.size else math.nan


def summarise(out: dict[str, np.ndarray], dt: float) -> list[dict[str, Any]]:
    """One row per policy: outcome counts (they add up to the cases) and the measures.

    Return and reward terms average over the cases that performed a lane change; duration,
    peak lateral acceleration, peak yaw rate and overshoot over the successful ones, which is
    what compares with human lane changes (~3-8 s). ``timeout_*`` are medians over the
    timeouts of the final |offset| (m), |heading| (rad) and |yaw rate| (rad/s), to set beside
    the success box.
    """
    rows = []
    for p in range(out["reason"].shape[0]):
        reason, performed = out["reason"][p], out["performed"][p]
        ok = reason == OUTCOMES.index("success")
        late = reason == OUTCOMES.index("timeout")
        n_perf = int(performed.sum())
        rows.append(
            {
                "cases": int(reason.size),
                "performed": n_perf,
                **{name: int((reason == code).sum()) for code, name in enumerate(OUTCOMES)},
                "success_rate": float(ok.sum() / n_perf) if n_perf else math.nan,
                "avg_return": _mean(out["ret"][p][performed]),
                "duration_s": _mean(out["steps"][p][ok] * dt),
                "peak_lat_acc": _mean(out["peak_lat_acc"][p][ok]),
                "peak_yaw_rate": _mean(out["peak_yaw_rate"][p][ok]),
                "overshoot_m": _mean(out["overshoot"][p][ok]),
                **{t: _mean(out[t][p][performed]) for t in ("r_s", "r_e", "r_d")},
                "timeout_offset_m": _median_abs(out["final_offset"][p][late]),
                "timeout_heading": _median_abs(out["final_psi"][p][late]),
                "timeout_yaw_rate": _median_abs(out["final_omega"][p][late]),
            }
        )
    return rows


def _run_config(run_dir: Path) -> config.Config:
    path = run_dir / "config.toml"
    if not path.is_file():
        raise EvalError(
            f"{run_dir} has no config.toml, so it is not a run directory; "
            "pass the --out directory of python -m jaxlc.sweep"
        )
    return config.load(path)


def _sidecar(path: Path) -> dict[str, Any]:
    return json.loads(path.with_suffix(".json").read_text(encoding="utf-8"))


def select_checkpoints(
    run_dir: Path, episodes: Sequence[int] | None = None, model: int | None = None
) -> list[tuple[Path, dict[str, Any]]]:
    """``(path, meta)`` of the checkpoints to evaluate, by model then episode.

    ``episodes=None``: ``default_episodes`` of the run's checkpoint spacing up to each
    model's last checkpoint."""
    if not run_dir.is_dir():
        raise EvalError(f"run directory {run_dir} does not exist; check the path")
    found = [(p, _sidecar(p)) for p in checkpoint.list_checkpoints(run_dir)]
    for p, m in found:
        missing = [k for k in ("model", "episode", "k") if not isinstance(m.get(k), int)]
        if missing:
            raise EvalError(
                f"checkpoint {p} has no {', '.join(missing)} in its JSON, so it was not "
                "written by python -m jaxlc.sweep; move it out of the run directory"
            )
    if not found:
        raise EvalError(
            f"no checkpoints in {run_dir / 'checkpoints'}; train first with "
            f"python -m jaxlc.sweep --out {run_dir}"
        )
    if model is not None:
        found = [(p, m) for p, m in found if m.get("model") == model]
        if not found:
            raise EvalError(f"no checkpoints of model {model} in {run_dir}; see its checkpoints/")
    have = sorted({m["episode"] for _, m in found})
    if episodes is not None:
        chosen = [(p, m) for p, m in found if m["episode"] in set(episodes)]
        if not chosen:
            raise EvalError(
                f"none of the episodes {sorted(episodes)} has a checkpoint; there are {have}"
            )
        return chosen
    every = have[0] if len(have) == 1 else int(min(np.diff(have)))
    # Per model, so one that stopped early still has its own last checkpoint evaluated.
    last = {}
    for _, m in found:
        last[m["model"]] = max(last.get(m["model"], 0), m["episode"])
    want = {i: set(default_episodes(every, e)) for i, e in last.items()}
    chosen = [(p, m) for p, m in found if m["episode"] in want[m["model"]]]
    return chosen or found


# The cell's axes beside k and memory, so that runs can be matched cell by cell (stats).
META_KEYS = ("label", "model", "seed", "k", "memory", "episode", "cell") + CELL_AXES[2:]
SCRIPTED = {"label": "scripted controller", **dict.fromkeys(META_KEYS[1:]), "checkpoint": None}


def _row_meta(path: Path, meta: dict[str, Any], run_dir: Path | None) -> dict[str, Any]:
    shown = path.relative_to(run_dir) if run_dir and path.is_relative_to(run_dir) else path
    return {**{k: meta.get(k) for k in META_KEYS}, "checkpoint": str(shown)}


def evaluate_run(
    run_dir: Path,
    episodes: Sequence[int] | None = None,
    *,
    cases: int = 100,
    model: int | None = None,
    seed: int = 0,
    max_steps: int = 1500,
    chunk: int = 32,
    traced: int = 4,
    devices: int = 1,
) -> dict[str, Any]:
    """Evaluate a run's checkpoints and the scripted baseline (row 0); writes
    ``run_dir/eval/eval.json``, ``eval.csv``, ``cases.npz``, ``traces.npz``; returns the
    JSON's content."""
    run_dir = Path(run_dir)
    chosen = select_checkpoints(run_dir, episodes, model)
    cfg = _run_config(run_dir)
    shapes = checkpoint.shapes_of(init_actor(cfg))
    actors = [checkpoint.load(p, expect_shapes=shapes)[0] for p, _ in chosen]
    metas = [SCRIPTED] + [_row_meta(p, m, run_dir) for p, m in chosen]
    kw = dict(cases=cases, seed=seed, max_steps=max_steps, chunk=chunk, traced=traced)
    out, trace, info = evaluate_policies(
        cfg, [None, *actors], [1] + [m["k"] for m in metas[1:]], devices=devices, **kw
    )
    result = _result(cfg, out, info, metas, kw)
    _write(run_dir / "eval", "eval", result)
    write_seed_stats(run_dir / "eval", result["rows"])
    ids = {
        "policy_model": np.asarray([-1 if m["model"] is None else m["model"] for m in metas]),
        "policy_episode": np.asarray([m["episode"] or 0 for m in metas]),
    }
    _save_npz(run_dir / "eval" / "cases.npz", {**out, **ids, **info})
    traced_side = info["side"][info["traced"]]
    _save_npz(
        run_dir / "eval" / "traces.npz",
        {**trace, **ids, "traced": info["traced"], "side": traced_side},
    )
    return result


def evaluate_checkpoint(
    path: Path,
    run_dir: Path | None = None,
    *,
    cases: int = 100,
    seed: int = 0,
    max_steps: int = 1500,
) -> dict[str, Any]:
    """Evaluate one checkpoint file and the scripted baseline; writes
    ``eval/<model dir>_<stem>.json`` (+ ``.csv``) in its run directory (or beside the file).

    The config is the run directory's (given, or the file's ``../../``); a lone file gets the
    paper's env and the network widths it holds."""
    path = Path(path)
    up = path.resolve().parents
    if run_dir is None and len(up) > 2 and (up[2] / "config.toml").is_file():
        run_dir = up[2]
    params, meta = checkpoint.load(path)
    if run_dir is not None:
        cfg = _run_config(Path(run_dir))
        checkpoint.load(path, expect_shapes=checkpoint.shapes_of(init_actor(cfg)))
    else:
        mlp = params["params"]["mlp"]
        hidden = [int(mlp[f"Dense_{i}"]["kernel"].shape[1]) for i in range(len(mlp) - 1)]
        cfg = config.load(None, [f"ddpg.hidden={hidden}"])
    metas = [SCRIPTED, _row_meta(path.resolve(), meta, run_dir and Path(run_dir).resolve())]
    kw = dict(cases=cases, seed=seed, max_steps=max_steps, traced=0)
    out, _, info = evaluate_policies(cfg, [None, params], [1, int(meta.get("k", 1))], **kw)
    result = _result(cfg, out, info, metas, kw)
    _write(Path(run_dir or path.parent) / "eval", f"{path.parent.name}_{path.stem}", result)
    return result


def _result(
    cfg: config.Config,
    out: dict[str, np.ndarray],
    info: dict[str, np.ndarray],
    metas: list[dict[str, Any]],
    kw: dict[str, Any],
) -> dict[str, Any]:
    """The content of eval.json: the setting, the cases, one row per policy."""
    rows = [{**m, **r} for m, r in zip(metas, summarise(out, cfg.env.dt), strict=True)]
    # The run up to the gap is the same for every policy, so these counts are the cases'.
    early = out["reason"][0][~info["performed"]]
    return {
        "config_hash": cfg.hash(),
        "cases": int(info["case"].size),
        "seed": kw["seed"],
        "max_steps": kw["max_steps"],
        "performed": int(info["performed"].sum()),
        "left": int((info["side"] > 0).sum()),
        "right": int((info["side"] < 0).sum()),
        "before_rl": {name: int((early == code).sum()) for code, name in enumerate(OUTCOMES)},
        "traced": info["traced"].tolist(),
        "success_box": {
            "offset_m": cfg.env.success_offset,
            "heading": cfg.env.success_heading,
            "yaw_rate": cfg.env.success_yaw_rate,
        },
        "rows": rows,
    }


def _write(out_dir: Path, name: str, result: dict[str, Any]) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    text = json.dumps(_json_safe(result), indent=1) + "\n"
    checkpoint.write_text_atomic(out_dir / f"{name}.json", text)
    checkpoint.write_text_atomic(out_dir / f"{name}.csv", _csv(result["rows"]))


def _json_safe(obj: Any) -> Any:
    # JSON has no NaN: an undefined mean (no successes) is null.
    if isinstance(obj, dict):
        return {k: _json_safe(v) for k, v in obj.items()}
    if isinstance(obj, list):
        return [_json_safe(v) for v in obj]
    if isinstance(obj, float) and not math.isfinite(obj):
        return None
    return obj


def _csv(rows: list[dict[str, Any]], fields: Sequence[str] = EVAL_FIELDS) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fields, extrasaction="ignore", lineterminator="\n")
    w.writeheader()
    for r in rows:
        w.writerow({k: r[k] if _defined(r.get(k)) else "" for k in fields})
    return buf.getvalue()


def write_seed_stats(out_dir: Path, rows: list[dict[str, Any]]) -> dict[str, Any]:
    """``cells.json`` (everything), ``cells.csv`` (per cell and checkpoint) and
    ``improvement.csv`` (P(X > Y) of the final success rate) from eval rows; returns the
    JSON's content."""
    cells = stats.cells_of(rows)
    doc = {
        "confidence": stats.CONFIDENCE,
        "resamples": stats.RESAMPLES,
        "note": stats.seeds_note(cells),
        "cells": stats.cell_table(cells),
        "final": stats.final_table(cells),
        "improvement": stats.improvement_table(cells),
        "claims": stats.claims(cells),
    }
    out_dir.mkdir(parents=True, exist_ok=True)
    text = json.dumps(_json_safe(doc), indent=1) + "\n"
    checkpoint.write_text_atomic(out_dir / "cells.json", text)
    for name, table in (("cells", doc["cells"]), ("improvement", doc["improvement"])):
        fields = list(table[0]) if table else []
        checkpoint.write_text_atomic(out_dir / f"{name}.csv", _csv(table, fields))
    return doc


def _eval_rows(run_dir: Path) -> list[dict[str, Any]]:
    path = run_dir / "eval" / "eval.json"
    if not path.is_file():
        raise EvalError(f"{path} is missing; run python -m jaxlc.evaluate {run_dir} first")
    return json.loads(path.read_text(encoding="utf-8"))["rows"]


def compare_runs(run_a: Path, run_b: Path, out: Path | None = None) -> Path:
    """Per-cell differences B - A of the mean success rate of two evaluated runs (their
    ``eval/eval.json``; nothing is re-evaluated): writes ``compare.md``, ``compare.csv`` and
    ``compare.png`` into ``out`` (default ``run_b/compare_<name of run_a>``); returns it."""
    run_a, run_b = Path(run_a), Path(run_b)
    table = stats.compare(stats.cells_of(_eval_rows(run_a)), stats.cells_of(_eval_rows(run_b)))
    out = Path(out) if out is not None else run_b / f"compare_{run_a.resolve().name}"
    out.mkdir(parents=True, exist_ok=True)
    checkpoint.write_text_atomic(out / "compare.csv", _csv(table, list(table[0])))
    from jaxlc import figures, report

    figures.fig_compare(table, run_a.name, run_b.name, out / "compare.png")
    text = report.compare_markdown(table, run_a, run_b)
    checkpoint.write_text_atomic(out / "compare.md", text)
    return out


def _save_npz(path: Path, arrays: dict[str, np.ndarray]) -> None:
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    checkpoint.write_bytes_atomic(path, buf.getvalue())


def rank_models(rows: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Final-checkpoint rows, best first: by success rate, then average return."""

    def key(r: dict[str, Any]) -> tuple[float, float]:
        sr, ret = r["success_rate"], r["avg_return"]  # None/NaN: no lane change performed
        return (sr if _defined(sr) else -1.0, ret if _defined(ret) else -math.inf)

    return sorted(final_rows(rows), key=key, reverse=True)


def format_table(rows: list[dict[str, Any]]) -> str:
    """Plain-text table of the evaluation rows for the terminal."""
    head = "policy                    seed    ep  perf  succ%   return  " + " ".join(
        f"{o[:4]:>4}" for o in OUTCOMES[1:] + OUTCOMES[:1]
    )
    lines = [head]
    for r in rows:
        sr = "   -" if r["success_rate"] != r["success_rate"] else f"{100 * r['success_rate']:5.1f}"
        ret = "      -" if r["avg_return"] != r["avg_return"] else f"{r['avg_return']:8.1f}"
        counts = " ".join(f"{r[o]:4d}" for o in OUTCOMES[1:] + OUTCOMES[:1])
        lines.append(
            f"{r['label'][:26]:26} {'-' if r['seed'] is None else r['seed']:>4} "
            f"{r['episode'] or '-':>5} {r['performed']:5d} {sr:>6} "
            f"{ret:>8}  {counts}"
        )
    return "\n".join(lines)


def _episodes_arg(text: str) -> list[int]:
    try:
        values = [int(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected episodes like 100,400,800, got {text!r}"
        ) from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one episode")
    return values


def _host_devices(args: argparse.Namespace) -> int:
    """``machine.host_devices_for`` a chunk of policies, each an actor over every case."""
    run_cfg = args.run_dir / "config.toml" if args.run_dir else None
    cfg = config.load(run_cfg) if run_cfg and run_cfg.exists() else config.Config()
    widths = (OBS_DIM, *cfg.ddpg.hidden, ACT_DIM)
    return machine.host_devices_for(args.chunk, machine.largest_product(args.cases, widths))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        prog="python -m jaxlc.evaluate",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    ap.add_argument("run_dir", type=Path, nargs="?", help="run directory of jaxlc.sweep")
    ap.add_argument("--episodes", type=_episodes_arg, default=None, help="e.g. 100,400,800")
    ap.add_argument("--cases", type=int, default=100, help="lane-change cases (default 100)")
    ap.add_argument("--model", type=int, default=None, help="evaluate only this model index")
    ap.add_argument("--checkpoint", type=Path, default=None, help="evaluate one .msgpack file")
    ap.add_argument("--seed", type=int, default=0, help="seed of the cases (default 0)")
    ap.add_argument("--max-steps", type=int, default=1500, help="step cap per case")
    ap.add_argument("--chunk", type=int, default=32, help="policies per compiled batch")
    ap.add_argument("--no-figures", action="store_true", help="skip figures (report still)")
    ap.add_argument(
        "--devices",
        type=int,
        default=None,
        help="devices to lay the policies over (default: every GPU; on a CPU, host devices as "
        "jaxlc/machine.py picks for --chunk policies over --cases; XLA_FLAGS overrides it)",
    )
    ap.add_argument(
        "--compare",
        nargs=2,
        type=Path,
        metavar=("RUN_A", "RUN_B"),
        help="compare two evaluated runs cell by cell (B - A); no evaluation",
    )
    ap.add_argument("--out", type=Path, default=None, help="--compare: output directory")
    args = ap.parse_intermixed_args(argv)
    try:
        if args.compare is not None:
            out = compare_runs(*args.compare, args.out)
            print(f"Wrote {out / 'compare.md'}, compare.csv, compare.png")
            return 0
        if args.cases < 1 or args.max_steps < 1 or args.chunk < 1:
            raise EvalError("--cases, --max-steps and --chunk must be at least 1")
        auto = args.devices is None
        machine.use_host_devices(_host_devices(args) if auto else args.devices)
        if args.checkpoint is not None:
            result = evaluate_checkpoint(
                args.checkpoint,
                args.run_dir,
                cases=args.cases,
                seed=args.seed,
                max_steps=args.max_steps,
            )
            print(format_table(result["rows"]))
            return 0
        if args.run_dir is None:
            raise EvalError("give a run directory (or --checkpoint FILE)")
        result = evaluate_run(
            args.run_dir,
            args.episodes,
            cases=args.cases,
            model=args.model,
            seed=args.seed,
            max_steps=args.max_steps,
            chunk=args.chunk,
            devices=len(jax.devices()) if auto else args.devices,
        )
        print(format_table(result["rows"]))
        from jaxlc import figures, report

        made = [] if args.no_figures else figures.make_all(args.run_dir)
        path = report.write_report(args.run_dir)
    except (EvalError, StatsError, CheckpointError, config.ConfigError, OSError) as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    print(f"Wrote {args.run_dir / 'eval'}, {len(made)} figures, {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
