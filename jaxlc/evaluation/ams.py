"""How close a policy comes to failing, by adaptive multilevel splitting on the simulator
(issue 78, SPEC "How close to failure"): ``python -m jaxlc.validate --method ams``.

Particles are lane changes of the validation's kind (``keys.VALIDATE``'s cases, traffic-only
warm-up, no noise), each drawn until N reach the RL phase: the estimand is per lane change.
A particle's score path is minus its margin of ``--kind`` so far (``measures.MARGINS``:
least clearance to any body, time left, distance to the border), read after each RL step by
the very functions the held-out evaluation folds; the margin is 0 exactly on the failure,
so P(margin <= m) is P(max score >= -m) and m = 0 is the failure probability.

The score as importance function: AMS keeps particles in proportion to how far their score
has come; its variance is least when the score orders states as the probability of going
on to fail from them (the committor). Minus the least clearance so far is a crude such
order: a lane change that has come within 0.3 m is nearer a collision than one that has
stayed 5 m away, but it reads neither speeds nor who brakes next. A poor importance
function costs variance, never bias (Bréhier et al. 2016): the estimate stays unbiased.

Unbiasedness: ``splitting``'s argument needs the future of a clone after its branch step to
be a fresh draw of the simulator's law given the state there, and that state to be its
parent's. Both hold: a particle's start (reset, warm-up, approach to the accepted gap) is a
function of its first key alone and is cached, since no clone branches before the RL phase
(the score is defined from the first RL step on); RL step t draws from ``fold_in(key of the
segment in force at t, env time)``: the unbranched particle's keys are the held-out
engine's ``fold_in(case key, time)`` (crude MC on the same keys is the engine's own rollout),
a clone's steps up to tau are its parent's, bit for bit, and those after come from a key no
other particle holds. The traffic's draws are the only randomness after the command (the
policy is deterministic), and they are thin: with the smoke config's scripted controller the
least clearance is often set at the command itself (a vehicle alongside in the next lane,
~1.9 m), in the cached start, where no split reaches. Branched at RL step 1 in 16 ways, 3
of 8 lane changes drew distinct paths even with braking events at 3,000 per vehicle-hour and
MOBIL on. With 32-64 particles the runs' clones collapsed onto one ancestor and the
runs went extinct (``extinct``, ``distinct``); with 200 they did not, and the curve agreed
with an independent crude MC where it sees >= 300 lane changes below the margin, but at ~3x
its steps for a wider interval: unbiased, no gain while the splits cannot move the margin.
The way on (not built): split before the command, the approach in the path, on a score
that reads the traffic there (the target lane's lead and lag gaps: the clearance the ego
would get if it went now; not the clearance now, which every vehicle passing alongside sets
to 1.9 m), capped below the target's level so that the event stays {margin <= m}; the
estimand then per case, divided by crude MC's share of cases that change lanes.
"""

from __future__ import annotations

import functools
import math
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc import config
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import measures, splitting, validation
from jaxlc.evaluation.engine import Cases, Policies, make_start_cases
from jaxlc.evaluation.results import EvalError
from jaxlc.evaluation.splitting import Chain
from jaxlc.learn.networks import make_networks
from jaxlc.sim.controller import baseline_action
from jaxlc.sim.env import EnvParams, LaneChangeEnv, action_dim
from jaxlc.sim.reward import step_limit

KINDS = tuple(measures.MARGINS)  # collision, timeout, out_of_bounds
BATCH = 256  # cases started per program while drawing lane changes


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


def starts(
    cfg: config.Config, n: int, seed: int, lo: int, max_steps: int, batch: int | None = None
) -> tuple[Cases, int, int]:
    """``(Cases (n,), next lo, cases started)``: the first ``n`` cases of ``keys.VALIDATE``'s
    stream from index ``lo`` on that reach the RL phase, started as the validation starts
    them (traffic-only warm-up), ``batch`` at a time (default: a power of two >= 2n, at most
    ``BATCH``)."""
    start = _start_program(cfg, max_steps)
    batch = min(BATCH, 1 << (2 * n - 1).bit_length()) if batch is None else batch
    got: list[Cases] = []
    have, begun = 0, 0
    while have < n:
        cs = start(streams.stream(seed, streams.VALIDATE, range(lo, lo + batch)))
        keep = np.nonzero(np.asarray(cs.performed))[0][: n - have]
        got.append(jax.tree.map(lambda a, keep=keep: a[keep], cs))
        have, begun, lo = have + keep.size, begun + batch, lo + batch
        if begun > 100 * n:
            raise EvalError(f"fewer than 1 in 100 cases performs a lane change ({have})")
    return jax.tree.map(lambda *xs: jnp.concatenate(xs), *got), lo, begun


@functools.lru_cache(maxsize=4)
def _start_program(cfg: config.Config, max_steps: int) -> Any:
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    return jax.jit(make_start_cases(base, max_steps, traffic_warmup=True))


def make_run(base: EnvParams, actor_apply: Any, kind: str, max_steps: int) -> Any:
    """``(pol, cs) -> run(chain) -> (T,)`` with T the manoeuvre's step cap: minus the margin of
    ``kind`` after each RL step of the particle whose first key is one of ``cs.key`` (its
    cached start), held once the manoeuvre ends. ``pol``: one policy (``Policies`` leaves
    without the policies axis)."""
    env, limit = LaneChangeEnv(), int(step_limit(base))
    fn = {m.name: m for m in measures.BUILTIN}[measures.MARGINS[kind]]
    time_like = fn.reduce == "last"  # the time left: the current value, not the least

    def bind(pol: Policies, cs: Cases) -> Any:
        p = base.replace(k=pol.k)

        def run(chain: Chain) -> jax.Array:
            i = jnp.argmax(jnp.all(cs.key == chain.keys[0], axis=-1))  # the particle's start
            s0, obs0 = jax.tree.map(lambda a: a[i], cs.state), cs.obs[i]
            side, t0 = cs.side[i].astype(jnp.float32), s0.time

            def body(c):
                t, s, obs, margin, done, path = c
                mu = actor_apply(pol.actor, obs[None])[0]
                a = jnp.where(pol.scripted, baseline_action(obs[None], p)[0], mu)
                seg = jnp.sum(chain.steps <= t) - 1  # splitting.step_key at env time t0 + t
                key = jax.random.fold_in(jax.random.wrap_key_data(chain.keys[seg]), s.time)
                obs, s, _, _, _, info = env.step(key, s, a, p)
                step = measures.Step(
                    s, info["reason"], info["episode_steps"], 0.0, info, side, True,
                    0.0, 0.0, None, 0.0, 0.0,
                )  # fmt: skip
                v = fn.fn(step, p)
                margin = v if time_like else jnp.minimum(margin, v)
                done = (info["reason"] != 0) | (s.time >= max_steps)
                return t + 1, s, obs, margin, done, path.at[t].set(-margin)

            path = jnp.zeros(limit, jnp.float32)
            c = (jnp.int32(0), s0, obs0, jnp.float32(jnp.inf), t0 >= max_steps, path)
            t, *_, margin, _, path = jax.lax.while_loop(lambda c: ~c[4] & (c[0] < limit), body, c)
            return jnp.where(jnp.arange(limit) < t, path, -margin)  # held after the end

        return run

    return bind


@functools.lru_cache(maxsize=4)
def program(cfg: config.Config, kind: str, particles: int, kill: float, rounds: int, steps: int):
    """Jitted ``(key, pol, cs (N,), target) -> Splitting``: one AMS run of one policy on the
    lane changes ``cs``, scores minus ``kind``'s margin, ``target`` minus the margin sought."""
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    actor_net, _ = make_networks(cfg.ddpg, action_dim(cfg.env))
    bind = make_run(base, actor_net.apply, kind, steps)

    def one(key: jax.Array, pol: Policies, cs: Cases, target: jax.Array) -> splitting.Splitting:
        return splitting.splitting(
            bind(pol, cs),
            key,
            target,
            particles=particles,
            kill_fraction=kill,
            max_rounds=rounds,
            initial=cs.key,
        )

    return jax.jit(one)


def command(cfg: config.Config, rows: list[tuple], args: Any, out_dir: Any, peak: float) -> int:
    """``python -m jaxlc.validate --method ams``'s work on the chosen policies (``rows``:
    validate's ``model_rows``): each one's estimate printed, the files written."""
    results = []
    for actor, k, meta in rows:
        pol = validation.policies(cfg, actor, k)
        results.append(r := estimate(cfg, meta, args, pol, peak))
        print(
            f"{r['meta']['label']}: P({args.kind} margin <= {args.margin:g}) {r['estimate']:.3g} "
            f"[{r['lo']:.3g}, {r['hi']:.3g}] per lane change, {r['wall_s']} s"
        )
        if any(r["extinct"]):
            print(
                f"  {sum(r['extinct'])} of {len(r['extinct'])} runs went extinct: their clones "
                f"drew no future of their own (distinct final paths {min(r['distinct']):.0%} at "
                "least); the margin is set before the splits reach it"
            )
    print(f"Wrote {write(out_dir, results)}")
    return 0


def estimate(cfg: config.Config, meta: dict, a: Any, pol: Policies, peak: float) -> dict:
    """``a.repeats`` independent AMS runs of one policy (``a``: validate's arguments): the
    estimate of P(margin <= a.margin) per lane change with Cox's 95% interval, the curve
    P(margin <= m) beside crude MC's on the runs' initial particles, the nearest misses."""
    import time

    run = program(cfg, a.kind, a.particles, a.kill, a.max_rounds, a.max_steps)
    lo, key, runs, t0 = 0, jax.random.PRNGKey(a.seed), [], time.perf_counter()
    pol = jax.tree.map(lambda x: x[0], pol)  # one policy, no axis
    started, rl_steps = 0, 0
    for r in range(a.repeats):
        cs, lo, begun = starts(cfg, a.particles, a.seed, lo, a.max_steps)
        res = jax.device_get(run(jax.random.fold_in(key, r), pol, cs, -a.margin))
        started += begun
        rl_steps += int(res.trajectories) * res.paths.shape[1]
        runs.append((res, np.asarray(cs.key)))
    wall = time.perf_counter() - t0
    ests = np.asarray([float(res.estimate) for res, _ in runs])
    mean, ci_lo, ci_hi = splitting.interval(ests, log=True)
    first = np.concatenate([-np.asarray(res.first) for res, _ in runs])  # crude MC's margins
    grid = np.unique(np.concatenate([[a.margin], np.quantile(first, np.linspace(0, 0.5, 26))]))
    per = np.asarray([_curve_of(res, a.particles, grid) for res, _ in runs])  # (R, m)
    rows = []
    for j, m in enumerate(grid):
        k = int((first <= m).sum())
        lo_cp, hi_cp = _cp(k, first.size)
        _, lo_a, hi_a = splitting.interval(per[:, j], log=True)
        rows.append(dict(margin=float(m), ams=float(per[:, j].mean()), ams_lo=lo_a,
                         ams_hi=hi_a, crude=k / first.size, crude_lo=lo_cp, crude_hi=hi_cp,
                         crude_n=k))  # fmt: skip
    return {
        "meta": meta,
        "method": "ams",
        "kind": a.kind,
        "margin": a.margin,
        "estimate": mean,
        "lo": ci_lo,
        "hi": ci_hi,
        "rel_halfwidth": (ci_hi - ci_lo) / 2 / mean if mean > 0 else math.nan,
        "repeats": ests.tolist(),
        "particles": a.particles,
        "kill": a.kill,
        "rounds": [int(res.rounds) for res, _ in runs],
        "stopped": [bool(res.stopped) for res, _ in runs],
        "distinct": [_distinct(res) for res, _ in runs],
        # every particle tied at a level below the target: the estimate is 0 for want of
        # clones that drew futures of their own, not for want of failures (docstring)
        "extinct": [bool(res.stopped) and float(res.reached) == 0.0 for res, _ in runs],
        "cases_started": started,
        "rl_steps": rl_steps,
        "wall_s": round(wall, 1),
        "matmul_peak_gflops": peak,
        "curve": rows,
        "nearest": _nearest(runs),
    }


def _curve_of(res: splitting.Splitting, n: int, grid: np.ndarray) -> np.ndarray:
    """One run's P(margin <= m) at each margin of ``grid``, each unbiased."""
    return splitting.exceedance_at(res, n, -grid)


def _cp(k: int, n: int) -> tuple[float, float]:
    from jaxlc.evaluation.heldout import clopper_pearson

    return clopper_pearson(k, n)


def _distinct(res: splitting.Splitting) -> float:
    """Share of distinct score paths among the final particles: near 1 when clones drew
    futures of their own, low when the randomness left after a split was too thin."""
    paths = np.asarray(res.paths)
    return len({p.tobytes() for p in paths}) / paths.shape[0]


def _nearest(runs: list, keep: int = 5) -> list[dict]:
    """The particles that came closest, over every run: their margin and key chain (the
    first key is the case's, ``keys.VALIDATE``'s stream)."""
    rows = []
    for r, (res, _) in enumerate(runs):
        for i in np.argsort(-np.asarray(res.scores))[:keep]:
            used = np.asarray(res.chains.steps[i]) != splitting.UNUSED
            rows.append(dict(repeat=r, margin=float(-res.scores[i]),
                             steps=np.asarray(res.chains.steps[i])[used].tolist(),
                             keys=np.asarray(res.chains.keys[i])[used].tolist()))  # fmt: skip
    return sorted(rows, key=lambda d: d["margin"])[:keep]


def write(out_dir: Any, results: list[dict]) -> Any:
    """``ams.json``, ``ams_curve.csv`` (per policy and margin: AMS and crude MC with their
    95% intervals) and ``ams_curve.png`` in ``out_dir``; the json's path."""
    import csv
    import json

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    out_dir.mkdir(parents=True, exist_ok=True)
    (out_dir / "ams.json").write_text(json.dumps(results, indent=1, default=float) + "\n")
    fields = ["label", "kind", *results[0]["curve"][0]]
    with open(out_dir / "ams_curve.csv", "w", newline="") as f:
        w = csv.DictWriter(f, fields)
        w.writeheader()
        for res in results:
            for c in res["curve"]:
                w.writerow({"label": res["meta"]["label"], "kind": res["kind"], **c})
    fig, ax = plt.subplots(figsize=(6, 4))
    for res in results:
        c = {k: np.asarray([row[k] for row in res["curve"]]) for k in res["curve"][0]}
        line = ax.step(c["margin"], c["ams"], where="post", label=f"{res['meta']['label']} AMS")
        ax.fill_between(c["margin"], c["ams_lo"], c["ams_hi"], step="post", alpha=0.2,
                        color=line[0].get_color())  # fmt: skip
        seen = c["crude_n"] > 0
        ax.errorbar(c["margin"][seen], c["crude"][seen], fmt=".", color="k",
                    yerr=[c["crude"][seen] - c["crude_lo"][seen],
                          c["crude_hi"][seen] - c["crude"][seen]],
                    label="crude MC" if res is results[0] else None)  # fmt: skip
    ax.set_yscale("log")
    unit = "s" if results[0]["kind"] == "timeout" else "m"
    ax.set_xlabel(f"margin to {results[0]['kind'].replace('_', ' ')}, {unit}")
    ax.set_ylabel("P(margin ≤ m) per lane change")
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(out_dir / "ams_curve.png", dpi=120)
    plt.close(fig)
    return out_dir / "ams.json"
