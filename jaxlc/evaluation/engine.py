"""The rollout engine: a case's start and its manoeuvre, run on one scheduler (``spill``).

A *case* is one lane-change scenario: ``env.reset`` from a fixed key, then steps until the
first episode of that env ends (any reason, no_gap included) or ``max_steps`` pass. Until the
gap is accepted the action is ignored (the ego keeps its lane), so the run up to the RL phase
is the same for every policy: ``make_start_cases`` simulates it once per case, and
``make_rollout`` broadcasts those states to all policies and runs them, vmapped over policies
and cases, folding every measure of ``jaxlc.evaluation.measures`` over the manoeuvre's steps.
Step keys are ``fold_in(case key, env time)``, so the split changes no random draw. "Left" is
toward higher y (lane index up; y points left of the driving direction).

Both run on ``spill``: from ``SPILL_MIN_BATCH`` cases on, most cases step together and the
slowest finish in blocks, each case bit for bit as in one loop over the batch, so the quick
ones no longer wait on the slowest.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
from jax import Array

from jaxlc.evaluation import measures, safety
from jaxlc.evaluation import trace as traces
from jaxlc.evaluation.measures import Outcome, Step
from jaxlc.evaluation.trace import Trace
from jaxlc.learn import tree
from jaxlc.sim.controller import baseline_action
from jaxlc.sim.env import RL, EnvParams, EnvState, LaneChangeEnv, action_dim
from jaxlc.sim.observation import observation
from jaxlc.sim.reward import step_limit
from jaxlc.sim.road import origin_lane

SPILL = 16  # once at most 1/SPILL of a batch's cases still go, they finish in blocks of that many
# A smaller batch's slowest cases cost it little: it runs as one loop (one compiled step).
SPILL_MIN_BATCH = 4 * SPILL


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
    # A proposal's (jaxlc.validate): its records of the draws so far (state.drawn, the sum of
    # its env's info["tilt"], log ratios included); None otherwise.
    tilt: Array | None = None  # (cases, stats)


def spill(
    step: Callable[[Array, tuple], tuple],
    live: Callable[[Any], Array],
    c: tuple,
    *,
    axis: int,
    first: int | None = None,
    more: Callable[[Any], Array] = lambda clock: True,
) -> tuple:
    """Step every case of ``c = (clock, cases, kept)`` until none is live or ``more(clock)``
    fails: ``cases``' leaves hold the ``n`` cases along ``axis``; ``step(rows, c)`` advances
    the cases ``rows`` ``(r,)`` one step (``c``'s cases then theirs alone), ``live(cases)`` is
    ``(r,)`` bool; ``kept`` passes through every step (the trace).

    Below ``SPILL_MIN_BATCH`` cases, one loop over all. From it, ``first`` cases (default all;
    the rollout's: the share that performs a lane change in the paper's traffic, ~70%, any
    more finish in the blocks), live first, step together until at most ``n // SPILL`` go on;
    then blocks of that many, live first, each from the ``clock`` where the first part
    stopped. A case's steps depend on its own leaves alone, so the schedule changes the cost,
    never the values."""
    n = jax.tree.leaves(c[1])[0].shape[axis]
    at = (slice(None),) * axis  # the axes before the cases'

    def going(c: tuple, stop: int) -> Array:
        return more(c[0]) & (jnp.sum(live(c[1])) > stop)

    if n < SPILL_MIN_BATCH:
        return jax.lax.while_loop(lambda c: going(c, 0), partial(step, jnp.arange(n)), c)
    m = n // SPILL

    def part(c: tuple, size: int, stop: int) -> tuple:
        """Run ``size`` cases, live first, while more than ``stop`` of them go on."""
        clock, cases, kept = c
        rows = jnp.argsort(~live(cases), stable=True)[:size]  # (size,)
        sub = jax.tree.map(lambda a: a[at + (rows,)], cases)
        clock, sub, kept = jax.lax.while_loop(
            lambda s: going(s, stop), partial(step, rows), (clock, sub, kept)
        )
        return clock, jax.tree.map(lambda a, d: a.at[at + (rows,)].set(d), cases, sub), kept

    c = part(c, n if first is None else first, m)
    return jax.lax.while_loop(lambda c: going(c, 0), lambda c: (c[0], *part(c, m, 0)[1:]), c)


def _begin(base: EnvParams, env: LaneChangeEnv, traffic_warmup: bool) -> Callable:
    """``begin(key) -> (state, reason, k_run)``: a case's reset (``env.reset``'s
    ``traffic_only`` warm-up with ``traffic_warmup``) and its run key."""

    def begin(key: Array) -> tuple:
        k_reset, k_run = jax.random.split(key)
        _, state = env.reset(k_reset, base, traffic_only=traffic_warmup)
        return state, jnp.int32(0), k_run

    return begin


def _start_parts(
    base: EnvParams, max_steps: int, env: LaneChangeEnv | None, traffic_warmup: bool = False
) -> tuple:
    """``(begin, going, step, finish)`` of one case's start: ``begin`` (``_begin``) resets,
    ``step`` advances the carry one dt with no action while ``going``, ``finish(carry) ->
    Cases``. The carry is ``(state, reason, k_run)``."""
    env = LaneChangeEnv() if env is None else env
    zero, origin = jnp.zeros(action_dim(base)), origin_lane(base)
    begin = _begin(base, env, traffic_warmup)

    def going(c: tuple) -> Array:
        s, reason, *_ = c
        return (reason == 0) & (s.ego.phase != RL) & (s.time < max_steps)

    def step(c: tuple) -> tuple:
        s, _, k_run = c
        *_, s, _, _, _, info = env.step(jax.random.fold_in(k_run, s.time), s, zero, base)
        return s, info["reason"], k_run

    def finish(c: tuple) -> Cases:
        state, reason, k_run = c
        performed = (reason == 0) & (state.ego.phase == RL)
        side = jnp.where(performed, state.ego.target - origin, 0).astype(jnp.int32)
        obs = observation(state, base)
        # a proposal's statistics of the approach: the sum its env keeps in the state
        return Cases(state, obs, k_run, reason, performed, side, state.drawn)

    return begin, going, step, finish


def make_start_case(
    base: EnvParams, max_steps: int, env: LaneChangeEnv | None = None
) -> Callable[[Array], Cases]:
    """``key -> Cases`` (unbatched): reset, then step with no action until the RL phase
    begins, the episode ends before it, or ``max_steps`` pass (``env``: a proposal's, whose
    ``step`` adds ``info["tilt"]``, the sum of which it keeps in ``state.drawn``)."""
    begin, going, step, finish = _start_parts(base, max_steps, env)
    return lambda key: finish(jax.lax.while_loop(going, step, begin(key)))


def make_start_cases(
    base: EnvParams, max_steps: int, env: LaneChangeEnv | None = None, traffic_warmup: bool = False
) -> Callable[[Array], Cases]:
    """``keys (n, 2) -> Cases (n,)``: ``make_start_case`` over a batch on ``spill``, each case
    bit for bit as alone, so the slowest cases' approach (up to ``max_steps``) no longer holds
    the whole batch. ``traffic_warmup``: the cases are reset with ``env.reset``'s
    traffic-only warm-up (the validation's cases; the evaluation's keep the full one)."""
    begin, going, step, finish = _start_parts(base, max_steps, env, traffic_warmup)
    on = jax.vmap(going)

    def together(rows: Array, c: tuple) -> tuple:
        clock, cases, kept = c
        return clock, tree.where(on(cases), jax.vmap(step)(cases), cases), kept

    def start_cases(keys: Array, states: EnvState | None = None) -> Cases:
        """``states`` ``(n, ...)``: go on from them, the clock back at 0 and ``keys`` the run
        keys, instead of a reset (a chain's next lane change in the traffic its last left)."""
        c = jax.vmap(begin)(keys) if states is None else (
            states.replace(time=jnp.zeros_like(states.time)), jnp.zeros_like(states.time), keys
        )  # fmt: skip
        _, started, _ = spill(together, on, ((), c, ()), axis=0)
        return jax.vmap(finish)(started)

    return start_cases


def make_resets(
    base: EnvParams, env: LaneChangeEnv | None = None, traffic_warmup: bool = False
) -> Callable[[Array], tuple[EnvState, Array]]:
    """``keys (n, 2) -> (states, run keys)``: each case's reset as ``make_start_cases`` begins
    it; ``start_cases(run keys, states)`` then goes on as from ``start_cases(keys)``."""
    begin = _begin(base, LaneChangeEnv() if env is None else env, traffic_warmup)

    def resets(keys: Array) -> tuple[EnvState, Array]:
        states, _, run = jax.vmap(begin)(keys)
        return states, run

    return resets


def _start_step(
    cs: Cases, state: EnvState, side: Array, performed: Array, counted: Array, bcast: Callable
) -> Step:
    """The manoeuvre's start as step 0 (``(policies, cases)`` leaves): the case's reason, its
    approach's records (a proposal's), no reward or jerk yet."""
    zero = jnp.zeros(performed.shape, jnp.float32)
    tilt = jnp.zeros(cs.reason.shape + (0,)) if cs.tilt is None else cs.tilt  # (cases, stats)
    return Step(
        state=state,
        reason=bcast(cs.reason),
        steps=jnp.zeros(performed.shape, jnp.int32),
        reward=zero,
        info={},
        side=side,
        performed=performed,
        lat_jerk=zero,
        long_jerk=zero,
        counted=counted,
        tilt=bcast(tilt),
    )


def make_rollout(
    base: EnvParams,
    actor_apply: Callable,
    max_steps: int,
    env: LaneChangeEnv | None = None,
    final: bool = False,
) -> Callable:
    """``(Policies, Cases, traced) -> (Outcome, Trace)``: every policy on every case, from the
    start of its RL phase until it ends, ``max_steps`` env time or the manoeuvre's step cap
    (``env``: a proposal's, as ``make_start_case``'s), each measure of ``measures.of(base)``
    folded over its steps; ``traced`` ``(traced,)`` the cases whose frames are kept.
    ``final``: the states where each ended ``(policies, cases, ...)`` too, the env's next
    episode begun (its auto-reset), for a chain's next lane change."""
    env = LaneChangeEnv() if env is None else env
    limit = int(step_limit(base))  # RL steps before a timeout
    ms = measures.of(base)

    def rollout(pol: Policies, cs: Cases, traced: Array) -> tuple[Outcome, Trace]:
        n_pol, n = pol.k.shape[0], cs.reason.shape[0]
        bcast = partial(jax.tree.map, lambda a: jnp.broadcast_to(a, (n_pol,) + a.shape))
        state, obs, side = bcast(cs.state), bcast(cs.obs), bcast(cs.side).astype(jnp.float32)
        case_keys, performed = bcast(cs.key), bcast(cs.performed)  # (policies, cases, ...)
        trace = traces.empty(n_pol, traced.shape[0], limit + 2, base)
        trace = traces.record(trace, 0, state, traced, jnp.ones(trace.frames.shape, bool), base)

        def step_policy(k: Array, keys: Array, s: EnvState, a: Array) -> tuple:
            return jax.vmap(env.step, (0, 0, 0, None))(keys, s, a, base.replace(k=k))

        def body(rows: Array, c: tuple) -> tuple:
            """One step of the cases ``rows`` ``(r,)``; ``c``'s per-case leaves are theirs."""
            i, (state, obs, done, out, watch), trace = c
            mu = jax.vmap(actor_apply)(pol.actor, obs)  # (policies, r, action_dim)
            action = jnp.where(pol.scripted[:, None, None], baseline_action(obs, base), mu)
            keys = jax.vmap(jax.vmap(jax.random.fold_in))(case_keys[:, rows], state.time)
            new_obs, new, r, _, _, info = jax.vmap(step_policy)(pol.k, keys, state, action)
            live = ~done  # (policies, r); only live cases are in the RL phase
            watch, (lat_jerk, long_jerk, counted) = safety.observe(watch, new, base)
            s = Step(
                state=new,
                reason=info["reason"],
                steps=info["episode_steps"],
                reward=r,
                info=info,
                side=side[:, rows],
                performed=performed[:, rows],
                lat_jerk=lat_jerk,
                long_jerk=long_jerk,
                counted=counted,
                tilt=info.get("tilt", 0.0),
            )
            out = measures.fold(ms, out, s, live, base)
            done = done | (live & ((info["reason"] != 0) | (new.time >= max_steps)))
            # Finished cases freeze, so their last frame is where the manoeuvre ended.
            state, obs = tree.where(live, (new, new_obs), (state, obs))
            # The traced cases among rows: their position there, and whether present.
            at = rows[None, :] == traced[:, None]  # (traced, r)
            pos, present = jnp.argmax(at, axis=1), jnp.any(at, axis=1)
            trace = traces.record(trace, i + 1, state, pos, live[:, pos] & present, base)
            return i + 1, (state, obs, done, out, watch), trace

        watch, counted = safety.watch(state, base)
        start = _start_step(cs, state, side, performed, counted, bcast)
        cases = (state, obs, ~performed, measures.start(ms, start, base), watch)
        c = spill(
            body,
            lambda cases: ~jnp.all(cases[2], axis=0),  # (cases,) a policy still live
            (jnp.int32(0), cases, trace),
            axis=1,
            first=n - n // 4,
            more=lambda i: i <= limit,
        )
        _, (last, _, _, out, _), trace = c
        # A case still running here hit the cap: its reason stays 0, "unfinished".
        end = start.replace(state=last, reason=out["reason"], steps=out["steps"])
        return (measures.finish(ms, out, end, base), trace) + ((last,) if final else ())

    return rollout
