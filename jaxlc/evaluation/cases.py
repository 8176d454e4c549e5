"""Fixed lane-change cases and the jitted program that runs policies on them.

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
Outcome codes are those of ``jaxlc.evaluation.results.OUTCOMES``.
"""

from __future__ import annotations

import functools
from collections.abc import Callable, Sequence
from functools import partial
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
from jax import Array
from jax.sharding import Mesh
from jax.sharding import PartitionSpec as P

from jaxlc import config
from jaxlc.evaluation import safety
from jaxlc.evaluation.results import EvalError
from jaxlc.learn import tree
from jaxlc.learn.networks import make_networks
from jaxlc.learn.train import check_devices
from jaxlc.sim.collision import overlaps
from jaxlc.sim.controller import baseline_action
from jaxlc.sim.env import RL, EnvParams, EnvState, LaneChangeEnv, action_dim
from jaxlc.sim.leaders import vehicle_y
from jaxlc.sim.observation import OBS_DIM, observation, target_gaps
from jaxlc.sim.reward import COLLISION, step_limit
from jaxlc.sim.reward import names as reward_names
from jaxlc.sim.road import ego_yaw_rate, origin_lane, road_curvature

PROTOCOL = config.EvalConfig()  # the defaults of the [eval] table: cases, step cap, chunk
SPILL = 16  # make_start_cases: once at most 1/SPILL of a batch still approaches, it finishes apart
# A smaller batch's slowest cases cost it little: it runs as one vmapped loop (one compiled step).
SPILL_MIN_BATCH = 4 * SPILL
PROBE_BATCH = 512  # cases_for_lane_changes: the most cases started at once


@flax.struct.dataclass
class Policies:
    """Rows to evaluate; every leaf has a leading ``(policies,)`` axis."""

    actor: Any  # actor params pytree
    k: Array  # (policies,) int32 action-update step
    scripted: Array  # (policies,) bool: act with controller.baseline_action, not the actor


@flax.struct.dataclass
class Cases:
    """Every case at the moment its RL phase begins (or its episode ended without one)."""

    state: EnvState  # (cases, ...)
    obs: Array  # (cases, OBS_DIM)
    key: Array  # (cases, 2) key that step keys are folded from
    reason: Array  # (cases,) int32: end before the RL phase (no_gap, collision), else 0
    performed: Array  # (cases,) bool: reached the RL phase
    side: Array  # (cases,) int32: +1 toward higher y (left), -1 right, 0 no lane change
    # A proposal's (jaxlc.validate): the log likelihood ratio of the draws so far and their
    # sufficient statistics (info["log_w"], info["tilt"] of its env); 0, (cases, 0) otherwise.
    log_w: Array | float = 0.0  # (cases,)
    tilt: Array | None = None  # (cases, stats)


@flax.struct.dataclass
class Outcome:
    """Per policy and case ``(policies, cases)``; dynamics are over the RL steps."""

    reason: Array  # int32 outcome index (OUTCOMES)
    performed: Array  # bool
    ret: Array  # total return
    terms: dict[str, Array]  # each reward term's sum over the manoeuvre, by name
    steps: Array  # int32 RL steps of the manoeuvre
    peak_lat_acc: Array  # max |v * omega|, m/s^2
    peak_yaw_rate: Array  # max |yaw rate relative to the lane's| (omega when straight), rad/s
    overshoot: Array  # max distance past the target centre line, m (0 if none)
    # The ego at the manoeuvre's last step (NaN without one), so a timeout's cause shows:
    # short of the lane (offset < 0), swinging (large omega) or just outside the success box.
    final_offset: Array  # signed offset to the target centre line toward the target side, m
    final_psi: Array  # heading, rad
    final_omega: Array  # yaw rate relative to the lane's (env.ego_yaw_rate), rad/s
    # Safety and comfort over the manoeuvre (jaxlc.evaluation.safety), the start state included.
    peak_lat_jerk: Array  # max |lateral jerk| over a 0.5 s moving average, m/s^3
    peak_long_acc: Array  # max |longitudinal acceleration|, m/s^2
    peak_long_jerk: Array  # max |longitudinal jerk| over a 0.5 s moving average, m/s^3
    # UN R79's lane change manoeuvre (jaxlc.evaluation.safety): the RL step at which the body
    # first overlaps the target lane, and the first after it with the body wholly past the
    # origin lane; -1 until then.
    lcm_start: Array  # int32
    lcm_end: Array  # int32
    # Headway and TTC only where they count (safety.counted), else inf.
    min_ttc: Array  # (policies, cases, 3) min time-to-collision to lead, lag, own leader, s
    min_thw: Array  # (policies, cases, 3) min time headway, s
    # The collision, if any: the vehicle hit (index of safety.PARTNERS) and the ego's speed.
    partner: Array  # int32
    hit_speed: Array  # m/s (NaN without a collision)
    # The traffic's hazards (env.mobil, env.braking; 0 in the paper's traffic): cut-ins met
    # and braking events of the vehicles around the ego over the manoeuvre, and what the
    # vehicle hit was doing (index of safety.HAZARDS).
    cut_ins: Array  # int32
    brakes_near: Array  # int32
    hit_hazard: Array  # int32
    # A proposal's log likelihood ratio and statistics, the start case's included (Cases).
    log_w: Array  # float32
    tilt: Array  # (policies, cases, stats)
    # The terms' order (a pytree's dict comes back with its keys sorted).
    names: tuple[str, ...] = flax.struct.field(pytree_node=False, default=())


@flax.struct.dataclass
class Trace:
    """The drawn cases, frame 0 = start of the RL phase: ``(policies, traced, frames, ...)``;
    frames past a case's ``frames`` are 0."""

    x: Array  # ego front bumper, m
    y: Array  # ego centre line, m
    psi: Array
    v: Array  # ego speed, m/s
    frames: Array  # (policies, traced) int32 valid frames
    traffic_x: Array  # (..., lanes, slots)
    traffic_active: Array  # (..., lanes, slots) bool
    traffic_y: Array  # (..., lanes, slots) body centre lines, m (between lanes while changing)
    lead_x: Array  # target-lane lead vehicle (front bumper), valid where has_lead
    lag_x: Array
    has_lead: Array
    has_lag: Array
    curvature: Array  # (policies, traced) the case's road curvature, 1/m (figures bend it)


def case_keys(seed: int, cases: int) -> Array:
    """``(cases, 2)`` keys of the paper-protocol cases; case ``i`` is the same for any
    ``cases >= i + 1``."""
    root = jax.random.PRNGKey(seed)
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(jnp.arange(cases))


# Held-out cases fold this tag into their root first, so their keys are a stream of their own,
# apart from the protocol's (``fold_in(PRNGKey(seed), i)``) and the sweep's (splits of
# ``PRNGKey(0)`` with each model's seed folded in): a key shared by chance is as likely as a
# hash collision (tests/test_heldout.py finds none among the first 2,000 of seeds 0-2).
HELDOUT_TAG = 0x48454C44  # "HELD"


def heldout_keys(seed: int, cases: int) -> Array:
    """``(cases, 2)`` keys of held-out cases (disjoint from ``case_keys``' stream)."""
    root = jax.random.fold_in(jax.random.PRNGKey(seed), HELDOUT_TAG)
    return jax.vmap(lambda i: jax.random.fold_in(root, i))(jnp.arange(cases))


def keys_for_lane_changes(
    cfg: config.Config,
    lane_changes: int,
    seed: int,
    max_steps: int = PROTOCOL.max_steps,
    batch: int | None = None,
) -> Array:
    """The fewest held-out keys (``heldout_keys(seed, n)``) whose cases hold ``lane_changes``
    lane changes (``cases_for_lane_changes``' keys)."""
    return cases_for_lane_changes(cfg, lane_changes, seed, max_steps, batch)[0]


def cases_for_lane_changes(
    cfg: config.Config,
    lane_changes: int,
    seed: int,
    max_steps: int = PROTOCOL.max_steps,
    batch: int | None = None,
) -> tuple[Array, Cases]:
    """``(keys (n, 2), Cases (n,))``: the fewest held-out keys (``heldout_keys(seed, n)``)
    whose cases hold ``lane_changes`` lane changes, and those cases started. Cases are started
    ``batch`` at a time until enough reach the RL phase (default: the power of two above
    ``lane_changes`` and a quarter more, at most ``PROBE_BATCH``); a case starts bit for bit
    as alone, so the batch changes the cost, never the cases."""
    if batch is None:
        batch = min(PROBE_BATCH, 1 << (lane_changes + lane_changes // 4).bit_length())
    start, _ = programs(cfg, max_steps)
    started: list[Cases] = []
    performed: list[np.ndarray] = []
    total = 0  # lane changes among the cases started so far
    while total < lane_changes:
        lo = batch * len(performed)
        started.append(start(heldout_keys(seed, lo + batch)[lo:]))
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
    return heldout_keys(seed, n), cs


@functools.lru_cache(maxsize=8)
def programs(cfg: config.Config, max_steps: int, devices: int = 1) -> tuple[Any, Any]:
    """Jitted ``start_cases(keys) -> Cases`` and ``rollout(policies, cases, traced) ->
    (Outcome, Trace)`` for a config (cached: configs are frozen and hashable).

    With ``devices > 1`` the policies axis is laid over a 1-D mesh of the first ``devices``
    devices (``shard_map``, as the sweep lays its models): each device rolls out its block of
    policies on every case; the policy count must be a multiple of ``devices``."""
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


def _start_parts(
    base: EnvParams, max_steps: int, env: LaneChangeEnv | None, traffic_warmup: bool = False
) -> tuple:
    """``(begin, going, step, finish)`` of one case's start: ``begin(key) -> carry`` resets
    (``env.reset``'s ``traffic_only`` warm-up with ``traffic_warmup``),
    ``step`` advances the carry one dt with no action while ``going``, ``finish(carry) ->
    Cases``. The carry is ``(state, reason, log_w, tilt, k_run)``."""
    env = LaneChangeEnv() if env is None else env
    zero, origin = jnp.zeros(action_dim(base)), origin_lane(base)
    stats, env_step = getattr(env, "stats", 0), _step_of(env)

    def begin(key: Array) -> tuple:
        k_reset, k_run = jax.random.split(key)
        _, state = env.reset(k_reset, base, traffic_only=traffic_warmup)
        return state, jnp.int32(0), jnp.float32(0.0), jnp.zeros(stats, jnp.float32), k_run

    def going(c: tuple) -> Array:
        s, reason, *_ = c
        return (reason == 0) & (s.ego.phase != RL) & (s.time < max_steps)

    def step(c: tuple) -> tuple:
        s, _, log_w, tilt, k_run = c
        *_, s, _, _, _, info = env_step(jax.random.fold_in(k_run, s.time), s, zero, base, tilt)
        tilt = tilt + info.get("tilt", 0.0)
        return s, info["reason"], log_w + info.get("log_w", 0.0), tilt, k_run

    def finish(c: tuple) -> Cases:
        state, reason, log_w, tilt, k_run = c
        performed = (reason == 0) & (state.ego.phase == RL)
        side = jnp.where(performed, state.ego.target - origin, 0).astype(jnp.int32)
        obs = observation(state, base)
        return Cases(state, obs, k_run, reason, performed, side, log_w, tilt)

    return begin, going, step, finish


def _step_of(env: LaneChangeEnv) -> Callable:
    """``(key, state, action, params, tilt) -> env.step(...)``: a proposal's env (``stats``)
    also reads the statistics of its steps so far (``tilt``; its conditional tilts do)."""
    if getattr(env, "stats", 0):
        return lambda key, s, a, p, tilt: env.step(key, s, a, p, so_far=tilt)
    return lambda key, s, a, p, tilt: env.step(key, s, a, p)


def make_start_case(
    base: EnvParams, max_steps: int, env: LaneChangeEnv | None = None
) -> Callable[[Array], Cases]:
    """``key -> Cases`` (unbatched): reset, then step with no action until the RL phase
    begins, the episode ends before it, or ``max_steps`` pass (``env``: a proposal's, whose
    ``step`` adds ``info["log_w"]`` and ``info["tilt"]``, ``env.stats`` of them)."""
    begin, going, step, finish = _start_parts(base, max_steps, env)
    return lambda key: finish(jax.lax.while_loop(going, step, begin(key)))


def make_start_cases(
    base: EnvParams, max_steps: int, env: LaneChangeEnv | None = None, traffic_warmup: bool = False
) -> Callable[[Array], Cases]:
    """``keys (n, 2) -> Cases (n,)``: ``make_start_case`` over a batch, each case bit for bit
    as alone. From ``SPILL_MIN_BATCH`` cases on, the batch steps together while more than
    ``n // SPILL`` of its cases go on and the rest finish in blocks of that many, so the
    slowest cases' approach (up to ``max_steps``) no longer holds the whole batch.
    ``traffic_warmup``: the cases are reset with ``env.reset``'s traffic-only warm-up (the
    validation's cases; the evaluation's keep the full one)."""
    begin, going, step, finish = _start_parts(base, max_steps, env, traffic_warmup)
    alone = jax.vmap(lambda c: jax.lax.while_loop(going, step, c))

    def start_cases(keys: Array) -> Cases:
        if keys.shape[0] < SPILL_MIN_BATCH:
            return jax.vmap(finish)(alone(jax.vmap(begin)(keys)))
        m = keys.shape[0] // SPILL
        on = jax.vmap(going)

        def together(c: tuple) -> tuple:
            return tree.where(on(c), jax.vmap(step)(c), c)

        def block(c: tuple) -> tuple:
            rows = jnp.argsort(~on(c), stable=True)[:m]  # (m,) going cases first
            done = alone(jax.tree.map(lambda a: a[rows], c))
            return jax.tree.map(lambda a, d: a.at[rows].set(d), c, done)

        c = jax.lax.while_loop(lambda c: on(c).sum() > m, together, jax.vmap(begin)(keys))
        c = jax.lax.while_loop(lambda c: on(c).any(), block, c)
        return jax.vmap(finish)(c)

    return start_cases


def _empty_outcome(cs: Cases, n_pol: int, p: EnvParams) -> Outcome:
    pc = (n_pol, cs.reason.shape[0])
    f0, i0, nan = jnp.zeros(pc, jnp.float32), jnp.zeros(pc, jnp.int32), jnp.full(pc, jnp.nan)
    ttc, thw = safety.conflicts(cs.state, p)  # (cases, 3): the manoeuvre's start state
    counted, entered = safety.counted(cs.state, p, jnp.zeros(cs.reason.shape, bool))
    ttc, thw = (jnp.where(counted, x, jnp.inf) for x in (ttc, thw))
    start = jnp.broadcast_to(jnp.where(entered, 0, -1).astype(jnp.int32), pc)
    end = jnp.where(entered & safety.crossed(cs.state, p), start, -1)
    return Outcome(
        reason=jnp.broadcast_to(cs.reason, pc),
        performed=jnp.broadcast_to(cs.performed, pc),
        ret=f0,
        terms={n: f0 for n in reward_names(p)},
        steps=i0,
        peak_lat_acc=f0,
        peak_yaw_rate=f0,
        overshoot=jnp.full(pc, -jnp.inf),
        final_offset=nan,
        final_psi=nan,
        final_omega=nan,
        peak_lat_jerk=f0,
        peak_long_acc=f0,
        peak_long_jerk=f0,
        lcm_start=start,
        lcm_end=end,
        min_ttc=jnp.broadcast_to(ttc, pc + (3,)),
        min_thw=jnp.broadcast_to(thw, pc + (3,)),
        partner=i0,
        hit_speed=nan,
        cut_ins=i0,
        brakes_near=i0,
        hit_hazard=i0,
        log_w=jnp.broadcast_to(jnp.asarray(cs.log_w, jnp.float32), pc),
        tilt=jnp.broadcast_to(_tilt_of(cs), pc + _tilt_of(cs).shape[1:]),
        names=reward_names(p),
    )


def _tilt_of(cs: Cases) -> Array:
    """``(cases, stats)`` a proposal's statistics of the start cases (``(cases, 0)`` none)."""
    return jnp.zeros(cs.reason.shape + (0,)) if cs.tilt is None else cs.tilt


def _accumulate(
    out: Outcome,
    live: Array,
    new: EnvState,
    r: Array,
    info: dict[str, Array],
    side: Array,
    jerk: tuple[Array, Array],
    counted: Array,
    p: EnvParams,
) -> Outcome:
    """Fold one step into the outcome; only ``live`` ``(policies, cases)`` entries change
    (``jerk``: the step's windowed lateral and longitudinal jerks; ``counted``:
    ``(policies, cases, 3)``, the vehicles whose headway and TTC count at this step,
    ``safety.counted``)."""

    def add(acc: Array, value: Array) -> Array:
        return acc + jnp.where(live, value, 0.0)

    def peak(acc: Array, value: Array) -> Array:
        return jnp.maximum(acc, jnp.where(live, value, acc))

    def last(acc: Array, value: Array) -> Array:
        return jnp.where(live, value, acc)

    toward = info["offset"] * side  # signed toward the target side
    # The yaw rate the success test reads: relative to the lane's (omega on a straight road).
    yaw = ego_yaw_rate(new.ego, jnp.broadcast_to(road_curvature(new, p), live.shape), p)
    ttc, thw = (jnp.where(counted, x, jnp.inf) for x in safety.conflicts(new, p))
    step, entered = info["episode_steps"], counted[..., 0]  # counted: (lead, lag, own)
    starts = live & entered & (out.lcm_start < 0)
    ends = live & entered & safety.crossed(new, p) & (out.lcm_end < 0)
    return out.replace(
        reason=jnp.where(live, info["reason"], out.reason),
        ret=add(out.ret, r),
        terms={n: add(v, info[n]) for n, v in out.terms.items()},
        steps=jnp.where(live, info["episode_steps"], out.steps),
        peak_lat_acc=peak(out.peak_lat_acc, jnp.abs(new.ego.v * new.ego.omega)),
        peak_yaw_rate=peak(out.peak_yaw_rate, jnp.abs(yaw)),
        overshoot=peak(out.overshoot, toward),
        final_offset=last(out.final_offset, toward),
        final_psi=last(out.final_psi, new.ego.psi),
        final_omega=last(out.final_omega, yaw),
        peak_lat_jerk=peak(out.peak_lat_jerk, jnp.abs(jerk[0])),
        peak_long_acc=peak(out.peak_long_acc, jnp.abs(new.ego.accel)),
        peak_long_jerk=peak(out.peak_long_jerk, jnp.abs(jerk[1])),
        lcm_start=jnp.where(starts, step, out.lcm_start),
        lcm_end=jnp.where(ends, step, out.lcm_end),
        min_ttc=jnp.where(live[..., None], jnp.minimum(out.min_ttc, ttc), out.min_ttc),
        min_thw=jnp.where(live[..., None], jnp.minimum(out.min_thw, thw), out.min_thw),
        cut_ins=out.cut_ins + (live & info.get("cut_in", False)),
        brakes_near=out.brakes_near + jnp.where(live, info.get("brake_near", 0), 0),
        log_w=add(out.log_w, info.get("log_w", 0.0)),
        tilt=out.tilt + jnp.where(live[..., None], info.get("tilt", 0.0), 0.0),
    )


def _collisions(out: Outcome, final: EnvState, cs: Cases, p: EnvParams) -> Outcome:
    """``out`` with the vehicle hit, what it was doing and the ego's speed, read from each
    case's ``final`` state (``(policies, cases, ...)``): a case freezes on the step its
    manoeuvre ends, so a collision's final state is the one of the collision."""
    hit = cs.performed & (out.reason == COLLISION)  # (policies, cases)
    kappa = jnp.broadcast_to(road_curvature(final, p), hit.shape)
    overlap = jax.vmap(jax.vmap(overlaps, (0, 0, None, 0)), (0, 0, None, 0))(
        final.traffic, final.ego, p, kappa
    )
    return out.replace(
        partner=jnp.where(hit, safety.partner(overlap, final.traffic, final.ego, p), 0),
        hit_speed=jnp.where(hit, final.ego.v, out.hit_speed),
        hit_hazard=jnp.where(hit, safety.hazard(overlap, final.traffic), 0),
    )


def _run_cases(going: Callable, body: Callable, c: tuple, n: int) -> tuple:
    """``make_rollout``'s loop over ``n`` cases: ``c`` is ``(i, per-case leaves (policies,
    cases, ...) whose third is ``done``, trace)``, ``body(rows, c)`` one step of the cases
    ``rows`` (``c``'s per-case leaves theirs). Below ``SPILL_MIN_BATCH`` cases, one loop
    over all; from it, the share of the cases that performs a lane change in the paper's
    traffic (~70%; any more finish in the blocks) runs together until at most ``n // SPILL``
    go on, then blocks of that many, live first, each from the time the first part stopped."""
    if n < SPILL_MIN_BATCH:
        return jax.lax.while_loop(going, partial(body, jnp.arange(n)), c)
    m = n // SPILL

    def live_count(c: tuple) -> Array:  # () cases with a policy still live
        return jnp.sum(~jnp.all(c[1][2], axis=0))

    def spill(c: tuple, size: int, stop: int) -> tuple:
        """Run ``size`` cases, live first, while more than ``stop`` of them go on."""
        i0, cases, trace = c
        rows = jnp.argsort(jnp.all(cases[2], axis=0), stable=True)[:size]  # (size,)
        sub = jax.tree.map(lambda a: a[:, rows], cases)
        i, sub, trace = jax.lax.while_loop(
            lambda s: going(s) & (live_count(s) > stop), partial(body, rows), (i0, sub, trace)
        )
        return i, jax.tree.map(lambda a, d: a.at[:, rows].set(d), cases, sub), trace

    c = spill(c, n - n // 4, m)
    return jax.lax.while_loop(going, lambda c: (c[0], *spill(c, m, 0)[1:]), c)


def make_rollout(
    base: EnvParams, actor_apply: Callable, max_steps: int, env: LaneChangeEnv | None = None
) -> Callable:
    """``(Policies, Cases, traced) -> (Outcome, Trace)``: every policy on every case, from the
    start of its RL phase until it ends, ``max_steps`` env time or the manoeuvre's step cap
    (``env``: a proposal's, as ``make_start_case``'s). From ``SPILL_MIN_BATCH`` cases on,
    most cases step together and the slowest finish in blocks (``_run_cases``), each case bit
    for bit as in one loop over the batch: the cases with no lane change and the quick
    manoeuvres no longer wait on the slowest."""
    env = LaneChangeEnv() if env is None else env
    limit = int(step_limit(base))  # RL steps before a timeout

    def rollout(pol: Policies, cs: Cases, traced: Array) -> tuple[Outcome, Trace]:
        n_pol, n = pol.k.shape[0], cs.reason.shape[0]
        bcast = functools.partial(jax.tree.map, lambda a: jnp.broadcast_to(a, (n_pol,) + a.shape))
        state, obs, side = bcast(cs.state), bcast(cs.obs), bcast(cs.side).astype(jnp.float32)
        case_keys = bcast(cs.key)  # (policies, cases, 2)
        trace = _empty_trace(n_pol, traced.shape[0], limit + 2, base)
        trace = _record(trace, 0, state, traced, jnp.ones((n_pol, traced.shape[0]), bool), base)

        env_step = _step_of(env)

        def step_policy(k: Array, keys: Array, s: EnvState, a: Array, tilt: Array) -> tuple:
            return jax.vmap(env_step, (0, 0, 0, None, 0))(keys, s, a, base.replace(k=k), tilt)

        def body(rows: Array, c: tuple) -> tuple:
            """One step of the cases ``rows`` ``(r,)``; ``c``'s per-case leaves are theirs."""
            i, (state, obs, done, out, hist, entered), trace = c
            mu = jax.vmap(actor_apply)(pol.actor, obs)  # (policies, r, action_dim)
            action = jnp.where(pol.scripted[:, None, None], baseline_action(obs, base), mu)
            keys = jax.vmap(jax.vmap(jax.random.fold_in))(case_keys[:, rows], state.time)
            new_obs, new, r, _, _, info = jax.vmap(step_policy)(
                pol.k, keys, state, action, out.tilt
            )
            live = ~done  # (policies, r); only live cases are in the RL phase
            (j_y, h_y), (j_x, h_x) = (
                safety.windowed_jerk(h, a, base.dt)
                for h, a in zip(hist, (safety.lateral_acc(new), new.ego.accel), strict=True)
            )
            jerk, hist = (j_y, j_x), (h_y, h_x)
            counted, entered = safety.counted(new, base, entered)
            out = _accumulate(out, live, new, r, info, side[:, rows], jerk, counted, base)
            done = done | (live & ((info["reason"] != 0) | (new.time >= max_steps)))
            # Finished cases freeze, so their last frame is where the manoeuvre ended.
            state, obs = tree.where(live, (new, new_obs), (state, obs))
            # The traced cases among rows: their position there, and whether present.
            at = rows[None, :] == traced[:, None]  # (traced, r)
            pos, present = jnp.argmax(at, axis=1), jnp.any(at, axis=1)
            trace = _record(trace, i + 1, state, pos, live[:, pos] & present, base)
            return i + 1, (state, obs, done, out, hist, entered), trace

        def going(c: tuple) -> Array:
            i, (_, _, done, *_), _ = c
            return (i <= limit) & jnp.any(~done)

        # The lateral and longitudinal accelerations of the last 0.5 s, each held at its
        # start value (the ego drove straight before; its jerk before the start is not known).
        a0 = safety.lateral_acc(state)
        window = a0.shape + (safety.jerk_window(base),)
        hist = tuple(jnp.broadcast_to(a[..., None], window) for a in (a0, state.ego.accel))
        out0 = _empty_outcome(cs, n_pol, base)
        _, entered = safety.counted(state, base, jnp.zeros(a0.shape, bool))
        cases = (state, obs, ~bcast(cs.performed), out0, hist, entered)
        c = (jnp.int32(0), cases, trace)
        _, (final, _, _, out, _, _), trace = _run_cases(going, body, c, n)
        # A case still running here hit the cap: its reason stays 0, "unfinished".
        out = _collisions(out.replace(overshoot=jnp.maximum(out.overshoot, 0.0)), final, cs, base)
        return out, trace

    return rollout


def _empty_trace(n_pol: int, n_traced: int, frames: int, p: EnvParams) -> Trace:
    shape = (n_pol, n_traced, frames)
    lanes = shape + (p.lanes, p.slots_per_lane)
    f, b = jnp.zeros(shape, jnp.float32), jnp.zeros(shape, bool)
    return Trace(
        x=f,
        y=f,
        psi=f,
        v=f,
        frames=jnp.zeros(shape[:2], jnp.int32),
        traffic_x=jnp.zeros(lanes, jnp.float32),
        traffic_active=jnp.zeros(lanes, bool),
        traffic_y=jnp.zeros(lanes, jnp.float32),
        lead_x=f,
        lag_x=f,
        has_lead=b,
        has_lag=b,
        curvature=jnp.zeros(shape[:2], jnp.float32),
    )


def _record(
    trace: Trace, i: Array | int, state: EnvState, traced: Array, live: Array, p: EnvParams
) -> Trace:
    """Write frame ``i`` of the traced cases, ``state``'s cases ``traced``, where ``live``
    ``(policies, traced)``, and count it there."""
    st = jax.tree.map(lambda a: a[:, traced], state)
    eg, tr, nb = st.ego, st.traffic, st.nb
    values = {
        "x": eg.x,
        "y": eg.y,
        "psi": eg.psi,
        "v": eg.v,
        "traffic_x": tr.x,
        "traffic_active": tr.active,
        "traffic_y": jax.vmap(jax.vmap(vehicle_y, (0, None)), (0, None))(tr, p),
        "lead_x": nb.a1_x,
        "lag_x": nb.b1_x,
        "has_lead": nb.has_a1,
        "has_lag": nb.has_b1,
    }

    def keep(old: Array, new: Array) -> Array:  # (policies, traced, ...) where live
        return jnp.where(live.reshape(live.shape + (1,) * (new.ndim - 2)), new, old)

    new = {
        k: getattr(trace, k).at[:, :, i].set(keep(getattr(trace, k)[:, :, i], v))
        for k, v in values.items()
    }
    kappa = jnp.broadcast_to(road_curvature(st, p), eg.x.shape).astype(jnp.float32)
    return trace.replace(
        **new, frames=trace.frames + live.astype(jnp.int32), curvature=keep(trace.curvature, kappa)
    )


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
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Evaluate actors (``None``: the scripted controller) with action-update steps ``ks`` on
    the protocol cases ``case_keys(seed, cases)``, or on the cases of ``keys`` if given, or on
    ``started`` (the cases of ``cases_for_lane_changes``, not started again).

    Returns numpy dicts ``(outcome (policies, cases), trace (policies, traced, ...),
    case info (cases,))``. Policies run in chunks of ``chunk`` (the last padded to full size,
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
    info = {"case": np.arange(cs.reason.shape[0]), "traced": idx, **case_info(cs, cfg)}
    return _concat(outs), _concat(traces), info


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
    return start(case_keys(seed, cases) if keys is None else keys)


def case_info(cs: Cases, cfg: config.Config) -> dict[str, np.ndarray]:
    """``(cases,)`` arrays of what each case was at the manoeuvre's start (the same for every
    policy): performed, side, the ego's speed, the target lane's gaps and the lag's speed at
    acceptance, whether the lag was drawn yielding."""
    eg, nb = cs.state.ego, cs.state.nb
    p = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    lead_gap, lag_gap = jax.device_get(target_gaps(cs.state, p))  # m along the target lane
    lead = np.where(nb.has_a1, lead_gap, np.nan)
    lag = np.where(nb.has_b1, lag_gap, np.nan)
    return {
        "performed": np.asarray(cs.performed),
        "side": np.asarray(cs.side),
        "accept_v": np.asarray(eg.v),
        "accept_lead_gap": np.asarray(lead),
        "accept_lag_gap": np.asarray(lag),
        "accept_lag_v": np.asarray(np.where(nb.has_b1, nb.b1_v, np.nan)),
        "yielding": np.asarray(eg.yielding),
    }


def columns(x: Any) -> dict[str, Any]:
    """An ``Outcome``/``Trace``'s arrays by name; the reward terms' among them, by theirs, in
    their order."""
    out: dict[str, Any] = {}
    for k, v in vars(x).items():
        if k == "names":
            continue
        out.update({n: v[n] for n in x.names} if isinstance(v, dict) else {k: v})
    return out


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
