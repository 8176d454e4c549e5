"""How close a policy comes to failing, by adaptive multilevel splitting on the simulator
(``python -m jaxlc.validate --method ams``; the design, why and evidence: docs/decisions.md,
"AMS on the simulator").

A particle is a case of the validation's stream (``keys.VALIDATE``), cached after its reset;
its path is the ego's wait, cruise, gap search and lane change, env step t keyed
``splitting.step_key(chain, t)`` (unbranched: the engine's ``fold_in(case key, t)``, so
``max_rounds=0`` is the validation's crude MC on the same cases). The estimand is per case
started: P(a lane change whose margin of ``--kind`` (``measures.MARGINS``) is <= m). The score
is minus the margin from the first RL step on, and before it ``approach_score``, below -cap
(m + ``--span``; by default by kind, ``cap_of``), so {max score >= -m'} is {margin <= m'} for
every m' < cap: the curve is read there. The score is a function of the path so far and a clone
replays its parent's keys to its branch, which is what ``splitting``'s unbiasedness needs; a
clone starts from its parent's latest saved state before the branch (before the parent's first
RL step or its own last branch: ``splitting``'s snapshots), the same path in fewer env steps.
Measured: no gain over crude MC where the traffic at the command decides the margin (the last
rounds branch ~0.7 s into the lane change, ~1 s before its closest moment); with ``--noise``
(the policy's actions under the training's exploration noise, a draw each step) and the cap by
kind, 9.4-11x fewer env steps than crude MC for its half-width on the border margin at p ~ 9e-4,
66-83x at p ~ 6e-5 (decisions.md, "The approach's cap by kind").
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from dataclasses import dataclass
from typing import Any

import flax.struct
import jax
import jax.numpy as jnp
import numpy as np

from jaxlc import config
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import measures, splitting, validation
from jaxlc.evaluation.engine import Policies, make_resets
from jaxlc.evaluation.heldout import clopper_pearson
from jaxlc.evaluation.numbers import Record, many
from jaxlc.evaluation.results import EvalError
from jaxlc.evaluation.splitting import Chain
from jaxlc.learn.ddpg import explore
from jaxlc.learn.networks import make_networks
from jaxlc.sim import collision
from jaxlc.sim.controller import baseline_action
from jaxlc.sim.env import CRUISE, RL, WAIT, EnvParams, EnvState, LaneChangeEnv, action_dim
from jaxlc.sim.observation import observation
from jaxlc.sim.reward import step_limit
from jaxlc.sim.road import origin_lane, road_curvature

KINDS = tuple(measures.MARGINS)  # collision, timeout, out_of_bounds
SPAN = 0.6  # m (s for timeouts): the cap's room above m or the margin's start (``cap_of``)
FAR = 100.0  # m: the approach's gap when no body is near


@flax.struct.dataclass
class Starts:
    """The particles' cases after their reset (``(n, ...)`` leaves): all before is cached."""

    state: EnvState  # at env time 0, the traffic warmed up, the ego not yet spawned
    obs: jax.Array  # (n, OBS_DIM)
    key: jax.Array  # (n, 2) the case's run key: its steps fold_in(key, time), the engine's


@dataclass
class Point(Record):
    """The curve at one margin: AMS (mean [Cox 95%] over the runs) and crude MC on the runs'
    initial particles (share [Clopper-Pearson 95%], ``crude_n`` below), per case."""

    margin: float
    ams: float
    ams_lo: float
    ams_hi: float
    crude: float
    crude_lo: float
    crude_hi: float
    crude_n: int


@dataclass
class Miss(Record):  # a nearest miss: its run, margin and key chain (first key: the case's)
    repeat: int
    margin: float
    steps: list
    keys: list


@dataclass
class Estimate(Record):
    """One policy's AMS result (``ams.json``)."""

    label: str
    kind: str
    margin: float  # m: the estimate is of P(lane change with margin <= m) per case
    cap: float  # the approach's scores stay below -cap; the curve is read below cap
    estimate: float
    lo: float
    hi: float
    rel_halfwidth: float
    repeats: list  # each run's estimate
    particles: int
    kill: float
    rounds: list
    stopped: list
    distinct: list  # share of distinct final paths per run
    extinct: list  # runs whose clones all tied below the target (estimate 0 by extinction)
    cases_started: int  # resets (warm-ups)
    trajectories: int  # cases simulated from their reset on, clones' re-runs included
    wall_s: float
    matmul_peak_gflops: float
    # what replays a miss (``replay``): the cases' stream seed, step cap, traffic, the policy
    seed: int = 0
    max_steps: int = 0
    traffic: list = dataclasses.field(default_factory=list)
    checkpoint: str | None = None  # relative to the run directory; None: scripted
    k: int = 1
    env_steps: int = 0  # the trajectories' env steps and the started cases' warm-ups: the work
    noise: float = 0.0  # --noise: sigma of the training's exploration noise on every action
    curve: list = many(Point)
    nearest: list = many(Miss)


@dataclass
class Ams(Record):
    """``ams.json``: one estimate per policy."""

    policies: list = many(Estimate)


def check(args: Any) -> None:
    """Refuse a bad ``--method ams`` setting of validate's ``args`` in one sentence."""
    kind, particles, kill, repeats = args.kind, args.particles, args.kill, args.repeats
    margin, rounds = args.margin, args.max_rounds
    if kind not in KINDS:
        raise EvalError(f"--kind {kind}: AMS splits on a margin, one of {', '.join(KINDS)}")
    if particles < 2:
        raise EvalError(f"--particles {particles}: AMS needs at least 2")
    if not 0.0 < kill < 1.0 or math.ceil(kill * particles) >= particles:
        raise EvalError(f"--kill {kill:g}: a fraction in (0, 1) that leaves a survivor")
    if repeats < 2:
        raise EvalError(f"--repeats {repeats}: the interval needs at least 2 independent runs")
    if not margin >= 0.0:
        raise EvalError(f"--margin {margin:g}: a margin is >= 0 (0: the failure itself)")
    if rounds < 0:
        raise EvalError(f"--max-rounds {rounds}: >= 0 (0: crude Monte Carlo)")
    validation.check_chain("ams", args.chain)
    if args.span is not None and not args.span > 0.0:
        raise EvalError(f"--span {args.span:g}: > 0 (the curve is read from m to m + span)")
    if not 0.0 <= args.noise <= 1.0:
        raise EvalError(f"--noise {args.noise:g}: a sigma in [0, 1] (tanh units, as training's)")


def cap_of(p: EnvParams, kind: str, margin: float, span: float | None) -> float:
    """The approach's cap: m + ``span``, or without one, ``SPAN`` above what only the lane change
    decides. The approach's gap foretells a collision margin, so for collisions that is m; it
    says nothing of the border or the time, so for those it is the margin every lane change
    starts from (the border past the target lane plus the lane's width; the manoeuvre's time
    limit): their own margin is the score from the first RL step on and no approach outranks
    it (a cap of m + 0.3 left ~1% of cases above the approach's ties: decisions.md, "The
    approach's cap by kind")."""
    if span is not None:
        return margin + span
    start = {"collision": margin, "out_of_bounds": p.border + p.lane_width}
    return max(float(start.get(kind, step_limit(p) * p.dt)), margin) + SPAN


def starts(cfg: config.Config, n: int, seed: int, lo: int) -> Starts:
    """Cases ``lo .. lo + n - 1`` of ``keys.VALIDATE``'s stream, reset as the validation
    resets them (``engine.make_resets``: the key split into reset and run keys)."""
    return _reset_program(cfg)(streams.stream(seed, streams.VALIDATE, range(lo, lo + n)))


@functools.lru_cache(maxsize=4)
def _reset_program(cfg: config.Config) -> Any:
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    resets = make_resets(base, traffic_warmup=True)

    def program(keys: jax.Array) -> Starts:
        states, run = resets(keys)
        return Starts(states, jax.vmap(observation, (0, None))(states, base), run)

    return jax.jit(program)


def approach_score(s: EnvState, p: EnvParams, cap: jax.Array) -> jax.Array:
    """``()`` minus (cap + the lengthwise gap to the nearest body in the ego's lane or a lane
    beside, the target's side once commanded, + the distance still to cruise): <= -cap."""
    ego, tr = s.ego, s.traffic
    c, lane_y, hx, _ = collision.frame(tr, ego, p, road_curvature(s, p))
    dx = jnp.abs(ego.x * c - hx - (tr.x * c - 0.5 * p.vehicle_length)) - hx
    dx = dx - 0.5 * p.vehicle_length  # (lanes, slots) bumper to bumper, < 0 alongside
    dy, side = lane_y - ego.y, ego.target - origin_lane(p)  # side 0 before the command
    near = tr.active & (jnp.abs(dy) < 1.5 * p.lane_width) & (dy * side > -0.5 * p.lane_width)
    gap = jnp.min(jnp.where(near, jnp.clip(dx, 0.0, FAR), FAR))
    to_go = jnp.where(ego.phase == CRUISE, jnp.maximum(p.command_distance - ego.x, 0.0), 0.0)
    to_go = jnp.where(ego.phase == WAIT, p.command_distance, to_go)
    return -(cap + gap + to_go)


def make_run(
    base: EnvParams, actor_apply: Any, kind: str, max_steps: int, noise: float = 0.0
) -> Any:
    """``(pol, cs, cap) -> run(chain) -> (max_steps,)``: the score path (docstring) of the case
    whose run key is the chain's first (``cs``: ``Starts``) after each env step, held once the
    case ends (``reason``) or reaches ``max_steps``. ``pol``: one policy (no policies axis).
    ``run(chain, record=True)``: the path and the state after each step ((max_steps, ...));
    ``resume=True``: the path, the env steps it took and its two snapshots, the state before
    its first RL step and before its chain's last branch, for ``splitting``'s clones to start
    from (``run(chain, (use, slot, snapshots), resume=True)``; the steps counted from there).
    ``noise``: the training's exploration noise (``ddpg.explore``) on each action, drawn from
    ``fold_in(step key, 1)``."""
    env, origin = LaneChangeEnv(), origin_lane(base)
    fn = {m.name: m for m in measures.BUILTIN}[measures.MARGINS[kind]]
    time_like = fn.reduce == "last"  # the time left: the current value, not the least

    def bind(pol: Policies, cs: Starts, cap: jax.Array) -> Any:
        p = base.replace(k=pol.k)

        def run(chain: Chain, start: Any = None, record: bool = False, resume: bool = False) -> Any:
            i = jnp.argmax(jnp.all(cs.key == chain.keys[0], axis=-1))  # the particle's case
            s0, obs0 = jax.tree.map(lambda a: a[i], cs.state), cs.obs[i]

            def act(o):
                mu = actor_apply(pol.actor, o[None])[0]
                return jnp.where(pol.scripted, baseline_action(o[None], p)[0], mu)

            def body(c):
                s, obs, margin, value, done, path, seen, snap = c
                rl = s.ego.phase == RL  # an RL step: the margin folds it, as the engine's
                if resume:  # before the first RL step, where the margin's rounds begin, and
                    # before the chain's own branch, where its descendants' rounds go on
                    take = jnp.stack([rl & (snap[0][0] == splitting.UNUSED), s.time == branch])
                    snap = splitting.snapshot(snap, take, s.time, (s, obs, margin, value))
                key, a = splitting.step_key(chain, s.time), act(obs)
                if noise > 0.0:  # static: without it the program is the one it always was
                    a = explore(jax.random.fold_in(key, 1), a, noise)
                a = jnp.where(rl, a, 0.0)  # the approach steps with no action (engine)
                obs, new, _, _, _, info = env.step(key, s, a, p)
                reason = info["reason"]
                side = (new.ego.target - origin).astype(jnp.float32)
                step = measures.Step(
                    state=new, reason=reason, steps=info["episode_steps"], reward=0.0,
                    info=info, side=side, performed=True, lat_jerk=0.0, long_jerk=0.0,
                    counted=None,
                )  # fmt: skip
                v = fn.fn(step, p)
                margin = jnp.where(rl, v if time_like else jnp.minimum(margin, v), margin)
                value = jnp.where(jnp.isfinite(margin), -margin, approach_score(new, p, cap))
                done = (reason != 0) | (new.time >= max_steps)
                if record:  # the state after each step, for pictures (``replay``)
                    seen = jax.tree.map(lambda b, x: b.at[s.time].set(x), seen, new)
                return new, obs, margin, value, done, path.at[s.time].set(value), seen, snap

            inf = jnp.float32(jnp.inf)
            seen = ()
            if record:
                seen = jax.tree.map(lambda x: jnp.zeros((max_steps, *x.shape), x.dtype), s0)
            here, snap, branch = (s0, obs0, inf, -inf), (), -1  # no snapshots: replays
            if resume:
                here, snap, branch = splitting.begin(chain, start, here)
            s1, obs1, margin1, value1 = here
            c = (s1, obs1, margin1, value1, s1.time >= max_steps, jnp.zeros(max_steps, jnp.float32))
            c = jax.lax.while_loop(lambda c: ~c[4], body, (*c, seen, snap))
            s, value, path, seen = c[0], c[3], c[5], c[6]
            path = jnp.where(jnp.arange(max_steps) < s.time, path, value)  # held after the end
            if resume:
                return path, s.time - s1.time, c[7]
            return (path, seen) if record else path

        return run

    return bind


def _bound(cfg: config.Config, kind: str, steps: int, noise: float) -> Any:
    """``make_run``'s ``bind`` for the run's env and actor network (``program``, ``replay``)."""
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    actor = make_networks(cfg.ddpg, action_dim(cfg.env))[0].apply
    return make_run(base, actor, kind, steps, noise)


@functools.lru_cache(maxsize=4)
def program(
    cfg: config.Config, kind: str, particles: int, kill: float, rounds: int, steps: int,
    noise: float = 0.0,
):  # fmt: skip
    """Jitted ``(key, pol, cs (N,), target, cap) -> Splitting``: one AMS run of one policy on
    the cases ``cs``; ``target`` minus the margin sought, ``cap`` the approach's (docstring)."""
    bind = _bound(cfg, kind, steps, noise)

    def one(key, pol: Policies, cs: Starts, target, cap) -> splitting.Splitting:
        return splitting.splitting(
            functools.partial(bind(pol, cs, cap), resume=True), key, target,
            particles=particles, kill_fraction=kill, max_rounds=rounds, initial=cs.key,
        )  # fmt: skip

    return jax.jit(one)


def estimate(cfg: config.Config, meta: dict, a: Any, pol: Policies, peak: float) -> Estimate:
    """``a.repeats`` independent AMS runs of one policy (``a``: validate's arguments): the
    estimate of P(lane change with margin <= a.margin) per case with Cox's 95% interval, the
    curve beside crude MC's on the runs' initial particles below the cap, the nearest misses."""
    run = program(cfg, a.kind, a.particles, a.kill, a.max_rounds, a.max_steps, a.noise)
    key, runs, t0 = jax.random.PRNGKey(a.seed), [], time.perf_counter()
    p = EnvParams.from_config(cfg.env)
    cap = cap_of(p, a.kind, a.margin, a.span)
    warm = p.warmup_steps  # a case's reset, paid once per start
    pol = jax.tree.map(lambda x: x[0], pol)  # one policy, no axis
    for r in range(a.repeats):
        cs = starts(cfg, a.particles, a.seed, r * a.particles)
        runs.append(jax.device_get(run(jax.random.fold_in(key, r), pol, cs, -a.margin, cap)))
    wall = time.perf_counter() - t0
    ests = np.asarray([float(res.estimate) for res in runs])
    mean, lo, hi = splitting.interval(ests, log=True)
    first = np.concatenate([-np.asarray(res.first) for res in runs])  # crude MC's draws
    # the least margin any run reached is a point of the curve: where no run reaches m, what
    # the runs can say is how likely a lane change comes that close
    least = min(-float(np.max(res.scores)) for res in runs)
    grid = np.linspace(a.margin, cap, 7)[:-1]
    near = np.linspace(a.margin, min(cap, a.margin + SPAN), 7)[:-1]  # where it is rare
    grid = np.unique(np.concatenate([grid, near, [least] if a.margin < least < cap else []]))
    per = np.asarray([splitting.exceedance_at(res, a.particles, -grid) for res in runs])
    curve = []
    for j, m in enumerate(grid):
        k = int((first <= m).sum())
        _, lo_a, hi_a = splitting.interval(per[:, j], log=True)
        curve.append(Point(float(m), float(per[:, j].mean()), lo_a, hi_a, k / first.size,
                           *clopper_pearson(k, first.size), k))  # fmt: skip
    return Estimate(
        label=meta["label"], kind=a.kind, margin=a.margin, cap=cap, estimate=mean, lo=lo, hi=hi,
        rel_halfwidth=(hi - lo) / 2 / mean if mean > 0 else math.nan, repeats=ests.tolist(),
        particles=a.particles, kill=a.kill, rounds=[int(res.rounds) for res in runs],
        stopped=[bool(res.stopped) for res in runs], distinct=[_distinct(res) for res in runs],
        # every particle tied at a level below the target: 0 for want of clones that drew
        # futures of their own, not for want of failures
        extinct=[bool(res.stopped) and float(res.reached) == 0.0 for res in runs],
        cases_started=a.repeats * a.particles,
        trajectories=sum(int(res.trajectories) for res in runs), wall_s=round(wall, 1),
        env_steps=sum(int(res.env_steps) for res in runs) + a.repeats * a.particles * warm,
        noise=a.noise,
        matmul_peak_gflops=peak, seed=a.seed, max_steps=a.max_steps, traffic=list(a.traffic),
        checkpoint=meta.get("checkpoint"), k=int(meta.get("k") or 1), curve=curve,
        nearest=_nearest(runs),
    )  # fmt: skip


def _distinct(res: splitting.Splitting) -> float:
    """Share of distinct score paths among the final particles: near 1 when clones drew
    futures of their own, low when the randomness left after a split was too thin."""
    paths = np.asarray(res.paths)
    return len({p.tobytes() for p in paths}) / paths.shape[0]


def _nearest(runs: list, keep: int = 5) -> list[Miss]:
    """The particles that came closest, over every run, with their key chains; one per margin
    in a run (clones that shared their parent's closest moment are one miss)."""
    out = []
    for r, res in enumerate(runs):
        for i in np.unique(-np.asarray(res.scores), return_index=True)[1][:keep]:
            steps = np.asarray(res.chains.steps[i])
            used = steps != splitting.UNUSED
            keys = np.asarray(res.chains.keys[i])[used].tolist()
            out.append(Miss(r, float(-res.scores[i]), steps[used].tolist(), keys))
    return sorted(out, key=lambda m: m.margin)[:keep]


@functools.lru_cache(maxsize=4)
def _case_program(
    cfg: config.Config, kind: str, steps: int, record: bool, noise: float = 0.0
) -> Any:
    bind = _bound(cfg, kind, steps, noise)
    return jax.jit(
        lambda pol, cs, cap, ch: jax.vmap(lambda c: bind(pol, cs, cap)(c, record=record))(ch)
    )


def replay(cfg: config.Config, est: Estimate, miss: Miss, pol: Policies, exact: bool) -> tuple:
    """A nearest miss run again from its key chain (``pol``: one policy, no axis): ``(margin,
    path (T,), states)``, T its steps, ``states`` after each step (host). ``exact``: the margin
    by AMS's own program on a batch the size the run computed the path in (its N for an
    unbranched particle, a re-run's k for a clone), so the saved one bit for bit; else NaN."""
    cs = starts(cfg, est.particles, est.seed, miss.repeat * est.particles)
    chain = Chain(jnp.asarray(miss.steps, jnp.int32), jnp.asarray(miss.keys, jnp.uint32))
    batch = est.particles if len(miss.steps) == 1 else max(1, math.ceil(est.kill * est.particles))
    margin = math.nan
    if exact:
        tiled = jax.tree.map(lambda x: jnp.broadcast_to(x, (batch, *x.shape)), chain)
        run = _case_program(cfg, est.kind, est.max_steps, False, est.noise)
        paths = run(pol, cs, est.cap, tiled)
        margin = float(-np.asarray(paths[0]).max())
    one = jax.tree.map(lambda x: x[None], chain)
    recorded = _case_program(cfg, est.kind, est.max_steps, True, est.noise)
    path, states = jax.device_get(recorded(pol, cs, est.cap, one))
    end = int(states.time[0].max())  # the steps the case took
    return margin, path[0, :end], jax.tree.map(lambda x: x[0, :end], states)
