"""Adaptive multilevel splitting (AMS): the probability that a score reaches a target, far below
what crude Monte Carlo sees (the estimator, its ties and its interval: docs/decisions.md,
"adaptive multilevel splitting's estimator and interval").

Bréhier, Gazeau, Goudenège, Lelièvre & Rousset (2016): N particles, a particle's score the max
of its score path; each round the level Z_j is the k-th smallest score (k = ceil(kill_fraction
N)), EVERY particle at or below it is killed (K_j >= k when scores tie) and replaced by a clone
of a survivor drawn uniformly, copied up to the step where it first went above Z_j. The rounds
stop at Z_j >= target or after ``max_rounds`` (``stopped`` says which; both unbiased). The
estimate is ``prod_j (1 - K_j / N) * (share of the final particles at the target)``, 0 on
extinction. A margin is a score negated: ``run`` returns -margin, the target is -m.

A particle is a chain of (branch step, key) segments, re-run from t = 0 by ``run(chain) ->
score path (T,)``, step t's key ``step_key(chain, t)`` = fold_in(key of the last segment whose
branch step <= t, t); a clone keeps its parent's segments to the branch and appends (tau + 1,
fresh key). A ``run`` may also keep snapshots of its state (``(path, steps, (at (S,), states
(S, ...)))``: the state before step ``at``) and take one back, ``run(chain, (use, slot, its
parent's snapshots))``: a clone starts from its parent's latest snapshot that comes before the
branch, and its path before that ``at`` is its parent's (``begin`` and ``snapshot`` keep two:
one where the run chooses, one before its chain's last branch). The 95% interval (``interval``) is
over R independent runs, Cox's lognormal (``log=True``) or Student's t.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats
from jax import Array

UNUSED = jnp.iinfo(jnp.int32).max  # branch step of an unused segment: never in force


@flax.struct.dataclass
class Chain:
    """A particle's randomness; the leading axes are particles' (N, or none for one)."""

    steps: Array  # (..., M) int32: branch step of each segment, increasing; UNUSED after
    keys: Array  # (..., M, 2) uint32: raw key data (saved to .npz as is), zeros when unused


@flax.struct.dataclass
class Splitting:
    """One AMS run: the estimate and what is needed to read or replay it."""

    estimate: Array  # () p-hat of P(score >= target)
    rounds: Array  # () int32: rounds applied (levels below the target)
    levels: Array  # (max_rounds,) level Z_j of each applied round; NaN after ``rounds``
    kills: Array  # (max_rounds,) int32 K_j of each applied round; 0 after
    lowest: Array  # (max_rounds, k) the k smallest scores before each applied round; NaN after
    reached: Array  # () share of the final particles with score >= target
    stopped: Array  # () bool: stopped by the level reaching the target, not max_rounds
    trajectories: Array  # () int32: trajectories run, chunk padding included (cost / T)
    env_steps: Array  # () int32: their steps, where ``run`` returns them (else 0)
    resumed: Array  # () int32: of those, clones started from a snapshot (module docstring)
    chains: Chain  # (N, M) the final particles' chains
    paths: Array  # (N, T) their score paths
    scores: Array  # (N,) their scores (max of the path)
    first: Array  # (N,) the initial particles' scores: crude MC's draws


@flax.struct.dataclass
class _Loop:
    """``splitting``'s loop state between rounds (``Splitting``'s fields as they grow)."""

    rounds: Array
    stopped: Array
    chains: Chain
    paths: Array
    levels: Array
    lowest: Array
    kills: Array
    log_weight: Array  # () log prod_j (1 - K_j / N)
    trajectories: Array
    env_steps: Array
    resumed: Array
    snaps: Any  # (N, S, ...) each particle's snapshots (``run``'s third output), or None


def step_key(chain: Chain, t: Array) -> Array:
    """Step t's key of one particle: fold_in(segment in force at t, t)."""
    segment = jnp.sum(chain.steps <= t) - 1  # steps increase; steps[0] = 0 so >= 0
    return jax.random.fold_in(jax.random.wrap_key_data(chain.keys[segment]), t)


def step_keys(chain: Chain, horizon: int) -> Array:
    """(T,) keys of steps 0..T-1 of one particle (for a run that draws all steps at once)."""
    return jax.vmap(lambda t: step_key(chain, t))(jnp.arange(horizon))


def initial_chains(key: Array, particles: int, segments: int) -> Chain:
    """(N, M) chains of one segment each: particle i is crude MC's draw i, its steps
    keyed fold_in(split(key, N)[i], t)."""
    first = jax.random.key_data(jax.random.split(key, particles))  # (N, 2)
    m = jnp.arange(segments)
    steps = jnp.where(m == 0, 0, UNUSED).astype(jnp.int32)  # (M,)
    keys = jnp.zeros((particles, segments) + first.shape[1:], first.dtype)
    return Chain(jnp.broadcast_to(steps, (particles, segments)), keys.at[:, 0].set(first))


def clone(chains: Chain, paths: Array, parent: Array, level: Array, fresh: Array) -> Chain:
    """(P,) chains: clone p copies ``chains[parent[p]]`` up to tau, the first step where
    its path (``paths``: (N, T)) went above ``level``, and branches at tau + 1 on
    ``fresh[p]`` ((P, 2) raw keys). Parents must be above the level somewhere."""
    tau = jnp.argmax(paths[parent] > level, axis=1)  # (P,) first True
    par = jax.tree.map(lambda x: x[parent], chains)  # (P, M)
    kept = jnp.sum(par.steps <= tau[:, None], axis=1)  # (P,) segments in force up to tau
    m = jnp.arange(par.steps.shape[1])[None, :]  # (1, M)
    steps = jnp.where(m < kept[:, None], par.steps, UNUSED)
    steps = jnp.where(m == kept[:, None], (tau + 1)[:, None], steps).astype(jnp.int32)
    keys = jnp.where((m < kept[:, None])[..., None], par.keys, 0)
    keys = jnp.where((m == kept[:, None])[..., None], fresh[:, None, :], keys)
    return Chain(steps, keys.astype(par.keys.dtype))


def begin(chain: Chain, start: Any, here: tuple) -> tuple:
    """For a ``run`` with two snapshots (module docstring): ``(here, snapshots, branch)``,
    where it begins (``here``: its state at t = 0, or ``start`` = (use, slot, the parent's
    snapshots) where used), its snapshots so far (``(at (2,), states (2, ...))``: slot 0 at a
    point of the run's choosing, the parent's where that precedes this chain's branch; slot 1
    before the chain's last branch; UNUSED: none yet) and that branch's step (-1: none)."""
    snap = (jnp.full(2, UNUSED, jnp.int32), jax.tree.map(lambda x: jnp.stack([x, x]), here))
    used = chain.steps < UNUSED  # (M,) segments in force somewhere
    branch = jnp.where(used.sum() > 1, jnp.max(jnp.where(used, chain.steps, 0)), -1)
    if start is not None:
        use, j, (at, states) = start
        keep = at[0] <= branch  # the parent's slot 0 is this chain's too
        first = jax.tree.map(lambda q, o: o.at[0].set(jnp.where(keep, q[0], o[0])), states, snap[1])
        snap = (snap[0].at[0].set(jnp.where(keep, at[0], UNUSED)), first)
        here = jax.tree.map(lambda q, h: jnp.where(use, q[j], h), states, here)
    return here, snap, branch


def snapshot(snap: tuple, take: Array, t: Array, now: tuple) -> tuple:
    """``snap`` with ``now``, the state before step ``t``, in the slots where ``take`` (2,)."""
    at, states = snap
    return jnp.where(take, t, at), jax.tree.map(
        lambda n, o: jnp.where(take.reshape((2,) + (1,) * n.ndim), n, o), now, states
    )


def _runs(run: Callable, chains: Chain, starts: Any = None) -> tuple[Array, Array, Any]:
    """``((P, T) score paths, () their env steps summed, (P, S, ...) snapshots or None)`` of
    ``run`` on P chains (from ``starts`` where given); ``run`` returns a path (steps then
    count 0), ``(path, the trajectory's env steps)`` or ``(path, steps, snapshots)``."""
    out = jax.vmap(run)(chains) if starts is None else jax.vmap(run)(chains, starts)
    path, steps, snaps = (*out, None)[:3] if isinstance(out, tuple) else (out, 0, None)
    return path.astype(jnp.float32), jnp.sum(steps).astype(jnp.int32), snaps


def _round(run: Callable[[Chain], Array], k: int, target: Array, rounds_key: Array, s: _Loop):
    """One round on the loop state ``s``: the level, the kills,
    the clones and their re-runs; a no-op that sets ``stopped`` when the level is at the
    target or all N tie (extinction)."""
    n = s.paths.shape[0]
    j, chains, paths = s.rounds, s.chains, s.paths
    scores = paths.max(axis=1)  # (N,)
    level = jnp.sort(scores)[k - 1]  # Z_j: the k-th smallest
    killed = scores <= level  # all ties go: the generalised AMS
    n_killed = killed.sum()
    stop = level >= target  # nothing left to kill below the target
    apply = ~stop & (n_killed < n)  # K_j = N: extinction, the share at the end is 0
    killed = killed & apply
    order = jnp.argsort(~killed, stable=True)  # (N,) killed first, then survivors
    kp, kf = jax.random.split(jax.random.fold_in(rounds_key, j))
    pick = jax.random.randint(kp, (n,), 0, jnp.maximum(n - n_killed, 1))
    parent = order[jnp.minimum(n_killed + pick, n - 1)]  # (N,) a survivor, uniform
    fresh = jax.random.key_data(jax.random.split(kf, n))  # (N, 2)
    clones = clone(chains, paths, parent, level, fresh)
    starts = None  # a clone starts from its parent's latest snapshot that precedes the branch
    if s.snaps is not None:
        snap = jax.tree.map(lambda x: x[parent], s.snaps)  # (N, S, ...) by slot
        ok = snap[0] <= (jnp.argmax(paths[parent] > level, axis=1) + 1)[:, None]  # (N, S)
        starts = (ok.any(axis=1), jnp.argmax(jnp.where(ok, snap[0], -1), axis=1), snap)
    chains = jax.tree.map(
        lambda c, o: jnp.where(killed.reshape((n,) + (1,) * (c.ndim - 1)), c, o),
        clones,
        chains,
    )
    # re-run only the killed, k at a time (a fixed shape; ties make K_j > k)
    chunks = jnp.where(apply, (n_killed + k - 1) // k, 0)

    def rerun(c, carry):
        paths, steps, resumed, snaps = carry
        slot = c * k + jnp.arange(k)  # (k,) positions in ``order``
        idx = order[jnp.minimum(slot, n - 1)]
        start = None if starts is None else jax.tree.map(lambda x: x[idx], starts)
        new, taken, snap = _runs(run, jax.tree.map(lambda x: x[idx], chains), start)
        at = jnp.where(slot < n_killed, idx, n)
        if start is not None:  # the path before the snapshot is the parent's
            at_start = jnp.take_along_axis(start[2][0], start[1][:, None], axis=1)  # (k, 1)
            before = start[0][:, None] & (jnp.arange(new.shape[1]) < at_start)
            new = jnp.where(before, paths[parent[idx]], new)
            snaps = jax.tree.map(lambda a, b: a.at[at].set(b, mode="drop"), snaps, snap)
            resumed = resumed + jnp.sum(start[0])  # padding too, as ``trajectories``
        return paths.at[at].set(new, mode="drop"), steps + taken, resumed, snaps

    carry = (paths, s.env_steps, s.resumed, s.snaps)
    paths, env_steps, resumed, snaps = jax.lax.fori_loop(0, chunks, rerun, carry)
    return _Loop(
        rounds=j + apply,
        stopped=~apply,
        chains=chains,
        paths=paths,
        levels=s.levels.at[j].set(jnp.where(apply, level, s.levels[j])),
        lowest=s.lowest.at[j].set(jnp.where(apply, jnp.sort(scores)[:k], s.lowest[j])),
        kills=s.kills.at[j].set(jnp.where(apply, n_killed, 0)),
        log_weight=s.log_weight + jnp.where(apply, jnp.log1p(-n_killed / n), 0.0),
        trajectories=s.trajectories + chunks * k,
        env_steps=env_steps,
        resumed=resumed,
        snaps=snaps,
    )


def splitting(
    run: Callable[[Chain], Array],
    key: Array,
    target: Array | float,
    *,
    particles: int,
    kill_fraction: float,
    max_rounds: int,
    initial: Array | None = None,
) -> Splitting:
    """AMS estimate of P(max_t run(chain)[t] >= target); jit with ``run``, ``particles``,
    ``kill_fraction``, ``max_rounds`` static, vmap over ``key`` for independent runs.

    ``run``: one chain -> (T,) score path (or ``(path, env steps)``: ``env_steps`` sums
    them; or ``(path, steps, snapshots)``: clones start from their parent's, module docstring),
    drawing step t from ``step_key(chain, t)``.
    The initial particles are ``initial_chains(split(key)[0], N, M)``: on the same key,
    ``max_rounds=0`` is crude MC on those draws. ``initial`` ``(N, 2)``: the initial
    particles' first segment keys instead (raw key data; a caller's chosen draws)."""
    n = particles
    k = max(1, math.ceil(kill_fraction * n))  # particles killed per round, ties aside
    first, rounds_key = jax.random.split(key)
    shape = jax.eval_shape(run, jax.tree.map(lambda x: x[0], initial_chains(first, 1, 1)))
    horizon = (shape[0] if isinstance(shape, tuple) else shape).shape[0]
    # branch steps strictly increase along a chain and lie in [0, T]; one segment per round
    segments = min(max_rounds, horizon) + 1
    chains = initial_chains(first, n, segments)
    if initial is not None:
        chains = chains.replace(keys=chains.keys.at[:, 0].set(initial.astype(chains.keys.dtype)))
    paths, env_steps, snaps = _runs(run, chains)  # (N, T), (), (N, ...) or None
    target = jnp.asarray(target, jnp.float32)

    def cond(s):
        return ~s.stopped & (s.rounds < max_rounds)

    s = _Loop(
        rounds=jnp.int32(0),
        stopped=jnp.bool_(False),
        chains=chains,
        paths=paths,
        levels=jnp.full(max(max_rounds, 1), jnp.nan, jnp.float32),  # (1,) when 0: traceable
        lowest=jnp.full((max(max_rounds, 1), k), jnp.nan, jnp.float32),
        kills=jnp.zeros(max(max_rounds, 1), jnp.int32),
        log_weight=jnp.float32(0.0),
        trajectories=jnp.int32(n),
        env_steps=env_steps,
        resumed=jnp.int32(0),
        snaps=snaps,
    )
    s = jax.lax.while_loop(cond, functools.partial(_round, run, k, target, rounds_key), s)
    scores = s.paths.max(axis=1)
    reached = jnp.mean(scores >= target)
    return Splitting(
        estimate=jnp.exp(s.log_weight) * reached,
        rounds=s.rounds,
        levels=s.levels[:max_rounds],
        lowest=s.lowest[:max_rounds],
        kills=s.kills[:max_rounds],
        reached=reached,
        stopped=s.stopped,
        trajectories=s.trajectories,
        env_steps=s.env_steps,
        resumed=s.resumed,
        chains=s.chains,
        paths=s.paths,
        scores=scores,
        first=paths.max(axis=1),
    )


def exceedance_at(result: Splitting, particles: int, z: np.ndarray) -> np.ndarray:
    """P(score >= z) at each of ``z``, each unbiased: the run with target z stops at the
    first round J whose level Z_J >= z (the same draws), so p(z) = prod_{j<J} (1 - K_j / N)
    times the share of round J's particles with score >= z; those below z < Z_J are among
    the k smallest (``lowest``). Past the last level: the final particles' share."""
    j = int(result.rounds)
    levels, lowest = np.asarray(result.levels[:j]), np.asarray(result.lowest[:j])
    weight = np.concatenate([[1.0], np.cumprod(1.0 - np.asarray(result.kills[:j]) / particles)])
    final = np.asarray(result.scores)
    out = np.empty(np.shape(z))
    for i, x in enumerate(np.asarray(z, float)):
        at = int(np.searchsorted(levels >= x, True))  # first round with Z_J >= x (levels rise)
        below = (final < x).sum() if at == j else (lowest[at] < x).sum()
        out[i] = weight[at] * (1.0 - below / particles)
    return out


def interval(
    estimates: np.ndarray, confidence: float = 0.95, log: bool = False
) -> tuple[float, float, float]:
    """(mean, lo, hi) for the mean of R >= 2 independent AMS estimates (each unbiased).

    ``log=False``: Student's t, lo clipped at 0. ``log=True``: Cox's interval for a
    lognormal mean (Olsson 2005, t quantile): exp(m + s^2/2 +- t sqrt(s^2/R + s^4/(2(R-1))))
    over y = log estimate. p-hat is a product of ~rounds factors, so near lognormal and
    right-skewed: a low mean comes with a low sd and t's interval misses low more often
    than high (the toy). Any zero (extinction) falls back to t."""
    x = np.asarray(estimates, float)
    r = x.size
    mean = float(x.mean())
    q = scipy.stats.t.ppf(0.5 + confidence / 2, r - 1)
    if log and (x > 0).all():
        y = np.log(x)
        v = y.var(ddof=1)
        centre, half = y.mean() + v / 2, q * math.sqrt(v / r + v**2 / (2 * (r - 1)))
        return mean, math.exp(centre - half), math.exp(centre + half)
    half = q * x.std(ddof=1) / math.sqrt(r)
    return mean, float(max(mean - half, 0.0)), float(mean + half)
