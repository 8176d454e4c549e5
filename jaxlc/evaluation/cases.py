"""Fixed lane-change cases, and every policy run on them (``evaluate_policies``).

Every policy (each checkpoint, and the scripted controller as a baseline row) sees the same
cases, with no exploration noise: the protocol's (``keys.stream(seed, PROTOCOL, ...)``), the
held-out lane changes (``cases_for_lane_changes``), or any keys given. ``programs`` gives the
jitted start of the cases and the rollout of the engine (``jaxlc.evaluation.engine``: a case,
its start and its manoeuvre; the measures: ``jaxlc.evaluation.measures``). Outcome codes are
those of ``jaxlc.evaluation.results.OUTCOMES``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxlc import config
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import measures
from jaxlc.evaluation.engine import Cases, Policies, make_rollout, make_start_cases
from jaxlc.evaluation.measures import Outcome
from jaxlc.evaluation.numbers import Record
from jaxlc.evaluation.results import EvalError
from jaxlc.evaluation.trace import pick_traced
from jaxlc.learn.networks import make_networks
from jaxlc.learn.train import check_devices
from jaxlc.sim.env import EnvParams, action_dim
from jaxlc.sim.observation import OBS_DIM, target_gaps

PROTOCOL = config.EvalConfig()  # the defaults of the [eval] table: cases, step cap, chunk
PROBE_BATCH = 512  # cases_for_lane_changes: the most cases started at once


def cases_for_lane_changes(
    cfg: config.Config,
    lane_changes: int,
    seed: int,
    max_steps: int = PROTOCOL.max_steps,
    batch: int | None = None,
) -> tuple[Array, Cases]:
    """``(keys (n, 2), Cases (n,))``: the fewest held-out keys (``keys.stream(seed,
    HELDOUT, range(n))``) whose cases hold ``lane_changes`` lane changes, and those cases
    started. Cases are started ``batch`` at a time until enough reach the RL phase (default:
    the power of two above ``lane_changes`` and a quarter more, at most ``PROBE_BATCH``); a
    case starts bit for bit as alone, so the batch changes the cost, never the cases."""
    if batch is None:
        batch = min(PROBE_BATCH, 1 << (lane_changes + lane_changes // 4).bit_length())
    start, _ = programs(cfg, max_steps)
    started: list[Cases] = []
    performed: list[np.ndarray] = []
    total = 0  # lane changes among the cases started so far
    while total < lane_changes:
        lo = batch * len(performed)
        started.append(start(streams.stream(seed, streams.HELDOUT, range(lo, lo + batch))))
        performed.append(np.asarray(started[-1].performed))
        total += int(performed[-1].sum())
        if len(performed) * batch > 100 * lane_changes:
            raise EvalError(
                f"fewer than 1 in 100 held-out cases performs a lane change "
                f"({total} of {len(performed) * batch}); "
                "check the config's traffic and gap settings"
            )
    n = int(np.searchsorted(np.cumsum(np.concatenate(performed)), lane_changes)) + 1
    cs = jax.tree.map(lambda *xs: jnp.concatenate(xs)[:n], *started)
    return streams.stream(seed, streams.HELDOUT, range(n)), cs


def programs(cfg: config.Config, max_steps: int, devices: int = 1) -> tuple[Any, Any]:
    """Jitted ``start_cases(keys) -> Cases`` and ``rollout(policies, cases, traced) ->
    (Outcome, Trace)`` for a config (cached: configs are frozen and hashable; a measure
    registered since makes new ones).

    With ``devices > 1`` the policies axis is laid over a 1-D mesh of the first ``devices``
    devices (``shard_map``, as the sweep lays its models): each device rolls out its block of
    policies on every case; the policy count must be a multiple of ``devices``."""
    return _programs(cfg, max_steps, devices, measures.registered())


@functools.lru_cache(maxsize=8)
def _programs(cfg: config.Config, max_steps: int, devices: int, registered: tuple) -> tuple:
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    actor_net, _ = make_networks(cfg.ddpg, action_dim(cfg.env))
    rollout = make_rollout(base, actor_net.apply, max_steps)
    if devices > 1:
        mesh = Mesh(np.asarray(jax.devices()[:devices]), ("models",))
        rollout = jax.shard_map(
            rollout,
            mesh=mesh,
            in_specs=(P("models"), P(), P()),
            out_specs=P("models"),
            check_vma=False,  # per-policy work only, no collectives to check
        )
    return jax.jit(make_start_cases(base, max_steps)), jax.jit(rollout)


def init_actor(cfg: config.Config, key: Array | None = None) -> Any:
    """Fresh actor params for ``cfg`` (a "random-params" baseline, and a shape template)."""
    actor_net, _ = make_networks(cfg.ddpg, action_dim(cfg.env))
    key = jax.random.PRNGKey(0) if key is None else key
    return actor_net.init(key, jnp.zeros((1, OBS_DIM), jnp.float32))


def evaluate_policies(
    cfg: config.Config,
    actors: Sequence[Any | None],
    ks: Sequence[int],
    *,
    cases: int = PROTOCOL.cases,
    seed: int = 0,
    keys: Array | None = None,
    max_steps: int = PROTOCOL.max_steps,
    chunk: int = PROTOCOL.chunk,
    traced: int = PROTOCOL.traced,
    devices: int = 1,
    started: Cases | None = None,
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], CaseInfo]:
    """Evaluate actors (``None``: the scripted controller) with action-update steps ``ks`` on
    the protocol cases (``keys.stream(seed, PROTOCOL, range(cases))``), or on the cases of
    ``keys`` if given, or on
    ``started`` (the cases of ``cases_for_lane_changes``, not started again).

    Returns ``(outcome (policies, cases), trace (policies, traced, ...))`` as numpy dicts and
    the cases' ``CaseInfo``. Policies run in chunks of ``chunk`` (the last padded to full size,
    so one compiled program serves all) to bound memory; a chunk is a multiple of ``devices``,
    over which its policies are laid.
    """
    check_devices(devices, EvalError)
    start, rollout = programs(cfg, max_steps, devices)
    cs = _the_cases(start, seed, cases, keys, started)
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
    return _concat(outs), _concat(traces), case_info(cs, cfg, idx)


def _the_cases(
    start: Callable[[Array], Cases],
    seed: int,
    cases: int,
    keys: Array | None,
    started: Cases | None,
) -> Cases:
    """``started`` if given, else the cases of ``keys``, else the protocol's ``cases``."""
    if started is not None:
        return started
    return start(streams.stream(seed, streams.PROTOCOL, range(cases)) if keys is None else keys)


@dataclass
class CaseInfo(Record):
    """``(cases,)`` arrays of what each case was at the manoeuvre's start, the same for every
    policy (``heldout_cases.npz`` and ``cases.npz`` keep them by these names): its index,
    ``traced`` (the indices of those drawn, ``(traced,)``), performed, side, the ego's speed,
    the target lane's gaps and the lag's speed at acceptance, whether the lag was drawn
    yielding."""

    case: np.ndarray
    traced: np.ndarray
    performed: np.ndarray
    side: np.ndarray
    accept_v: np.ndarray
    accept_lead_gap: np.ndarray  # m along the target lane, NaN: no lead
    accept_lag_gap: np.ndarray
    accept_lag_v: np.ndarray
    yielding: np.ndarray


def case_info(cs: Cases, cfg: config.Config, traced: np.ndarray) -> CaseInfo:
    """The ``CaseInfo`` of the cases ``cs``, ``traced`` those drawn."""
    eg, nb = cs.state.ego, cs.state.nb
    p = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    lead_gap, lag_gap = jax.device_get(target_gaps(cs.state, p))
    return CaseInfo(
        case=np.arange(cs.reason.shape[0]),
        traced=traced,
        performed=np.asarray(cs.performed),
        side=np.asarray(cs.side),
        accept_v=np.asarray(eg.v),
        accept_lead_gap=np.asarray(np.where(nb.has_a1, lead_gap, np.nan)),
        accept_lag_gap=np.asarray(np.where(nb.has_b1, lag_gap, np.nan)),
        accept_lag_v=np.asarray(np.where(nb.has_b1, nb.b1_v, np.nan)),
        yielding=np.asarray(eg.yielding),
    )


def columns(x: Any) -> dict[str, Any]:
    """An ``Outcome``/``Trace``'s arrays by name, in their order (any other object's
    attributes, ``names`` aside: tests hand in stand-ins)."""
    if isinstance(x, Outcome):
        return x.columns()
    return {k: v for k, v in vars(x).items() if k != "names"}


def _concat(parts: list[Any]) -> dict[str, np.ndarray]:
    """Chunks of an ``Outcome``/``Trace`` -> one dict of arrays along the policy axis."""
    cols = [columns(x) for x in parts]
    return {k: np.concatenate([c[k] for c in cols]) for k in cols[0]}


def evaluate_act(
    cfg: config.Config,
    act: Callable[[Array], Array],
    *,
    k: int = 1,
    cases: int = PROTOCOL.cases,
    seed: int = 0,
    keys: Array | None = None,
    max_steps: int = PROTOCOL.max_steps,
    started: Cases | None = None,
) -> dict[str, np.ndarray]:
    """Any learner's policy, given as a jittable ``act(obs (cases, OBS_DIM)) -> action (cases,
    1)``, on the same fixed cases as every checkpoint (or those of ``keys``, or ``started``, as
    ``evaluate_policies``): the outcome dict
    of ``evaluate_policies`` with one row (``jaxlc.evaluation.results.summarise`` turns it into
    a row)."""
    start, _ = programs(cfg, max_steps)  # the checkpoints' own (cached) case program
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    rollout = jax.jit(make_rollout(base, lambda _, obs: act(obs), max_steps))
    cs = _the_cases(start, seed, cases, keys, started)
    one = Policies(actor=jnp.zeros(1), k=jnp.asarray([k], jnp.int32), scripted=jnp.zeros(1, bool))
    out, _ = jax.device_get(rollout(one, cs, jnp.zeros(1, jnp.int32)))
    return {name: np.asarray(v) for name, v in columns(out).items()}
