"""A policy's failure probability per lane change, by crude Monte Carlo or importance sampling:
``estimate`` (``python -m jaxlc.validate`` is its command line).

A lane change is a held-out case (reset with the traffic-only warm-up, the approach, the
manoeuvre) from its own key stream (``keys.VALIDATE``), ``chunk`` cases per jitted ``program``
under a proposal (``EnvParams.draws``; crude MC: the traffic's own). ``kinds`` reads each lane
change's failures (any, each failed end, each norm of ``safety.NORMS`` violated). IS fits a
``mixture.Mixture`` on pilot chunks and draws each chunk from one of its components or the
traffic; ``Tally`` keeps each lane change's log ratios and kinds and the failures with their
keys, so the estimate and the worst cases can be read at any chunk, Ctrl-C included.
"""

from __future__ import annotations

import dataclasses
import functools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import scipy.stats
from tqdm import tqdm

from jaxlc import config
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import mixture, rare
from jaxlc.evaluation.cases import Policies, columns, init_actor, make_rollout, make_start_cases
from jaxlc.evaluation.engine import make_resets
from jaxlc.evaluation.heldout import lane_change_measures
from jaxlc.evaluation.mixture import Mixture
from jaxlc.evaluation.proposal import Proposal, Record, TiltedEnv
from jaxlc.evaluation.results import OUTCOMES, EvalError
from jaxlc.evaluation.safety import NORMS
from jaxlc.learn.networks import make_networks
from jaxlc.sim.env import EnvParams, action_dim
from jaxlc.sim.params import value_range

ENDS = ("collision", "out_of_bounds", "timeout", "unfinished")
KINDS = ("failure", *ENDS, *(f"norm_{name}" for name, *_ in NORMS))
CASE_CAP = 1000  # failures kept per model and kind, highest weight first


@functools.lru_cache(maxsize=4)
def program(cfg: config.Config, max_steps: int, tilted: bool, chain: int = 1) -> Callable:
    """Jitted ``(proposal, policies, keys (chunk, 2)) -> (Outcome, Trace)`` of one policy on a
    chunk of cases, under a ``Proposal`` (traced: ``EnvParams.draws``); ``tilted=False``: the
    simulator's own draws (the proposal, None, is ignored).

    ``chain`` > 1 (crude MC): each case drives ``chain`` lane changes in one traffic, the
    ego commanded again from the env's auto-reset after each (its approach, no warm-up),
    lane change ``j`` > 0 keyed ``fold_in(case key, j)``; the Outcome's ``(1, chain * chunk)``
    columns lane change after lane change (``j * chunk + case``), the Trace ``(chain, ...)``
    each one's of case 0. Lane change 0 is the unchained case bit for bit."""
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    actor_net, _ = make_networks(cfg.ddpg, action_dim(cfg.env))
    none = jnp.zeros(1, jnp.int32)  # case 0 traced (replay)

    def run(prop: Proposal | None, pol: Policies, keys: jax.Array) -> tuple:
        p, env = (base.replace(draws=prop), TiltedEnv()) if tilted else (base, None)
        start = make_start_cases(p, max_steps, env, traffic_warmup=True)
        if chain == 1:
            return make_rollout(p, actor_net.apply, max_steps, env)(pol, start(keys), none)
        rollout = make_rollout(p, actor_net.apply, max_steps, env, final=True)
        states, run0 = make_resets(p, env, traffic_warmup=True)(keys)  # one warm-up per case

        def next_one(c: tuple, j: jax.Array) -> tuple:
            # ended: every episode of the case so far ended, so the env's auto-reset spawned
            # the ego anew; one cut by max_steps (in its approach or mid-manoeuvre) leaves its
            # state where it stopped, never a new lane change's start: the chain ends there
            last, ended = c
            run = jnp.where(j == 0, run0, jax.vmap(jax.random.fold_in, (0, None))(keys, j))
            cs = start(run, last)
            out, trace, last = rollout(pol, cs.replace(performed=cs.performed & ended), none)
            ended &= out["reason"][0] != 0
            return (jax.tree.map(lambda a: a[0], last), ended), (out, trace)

        first = (states, jnp.ones(keys.shape[0], bool))
        _, (outs, traces) = jax.lax.scan(next_one, first, jnp.arange(chain))
        rows = (1, chain * keys.shape[0])
        out = jax.tree.map(lambda a: jnp.moveaxis(a, 0, 1).reshape(rows + a.shape[3:]), outs)
        return out, traces

    return jax.jit(run)


def policies(cfg: config.Config, actor: Any | None, k: int) -> Policies:
    """One policy: ``actor`` params, or the scripted controller (``None``)."""
    a = jax.tree.map(np.zeros_like, init_actor(cfg)) if actor is None else actor
    return Policies(
        actor=jax.tree.map(lambda x: jnp.asarray(x)[None], a),
        k=jnp.asarray([k], jnp.int32),
        scripted=jnp.asarray([actor is None]),
    )


def kinds(out: dict[str, np.ndarray], dt: float) -> np.ndarray:
    """``(cases, len(KINDS))`` bool: each failure kind of policy 0's lane changes."""
    reason = out["reason"][0]
    inside = lane_change_measures(out, 0, dt)
    cols = [reason != OUTCOMES.index("success")]
    cols += [reason == OUTCOMES.index(e) for e in ENDS]
    cols += [~inside[f"norm_{name}"] for name, *_ in NORMS]
    return np.stack(cols, axis=1)


def score(out: dict[str, np.ndarray], kind: str) -> np.ndarray:
    """``(cases,)`` how close a lane change came to failing so: minus its lowest TTC for a
    collision or a TTC norm, else the manoeuvre's length (a timeout is the longest)."""
    if kind in ("collision", "norm_min_ttc_s"):
        return -np.minimum(np.min(out["min_ttc"][0], axis=-1), 1e3)
    return out["steps"][0].astype(np.float64)


@dataclass
class Case:
    """A failure kept to replay: its case index and key, weight, kinds, end, the component
    that drew it (-1: the traffic's own) and the proposal at the shares so far (IS)."""

    index: int
    key: list[int]
    log_w: float
    kinds: list[str]
    reason: str
    component: int
    proposal: dict[str, Any] | None  # IS's mixture at the shares its chunks held (to weigh)
    model: int  # the policy: its index among those validated, label, checkpoint and k
    label: str
    checkpoint: str | None
    k: int
    method: str
    chain: int = 0  # its place in its case's chain of lane changes (``--chain``)


@dataclass
class Tally:
    """What the chunks so far found, per kept case (every lane change; every case started
    with ``ratio``, a window before acceptance): its log ratios to ``mix``'s components, its
    kinds and whether it performed; each chunk's component; the failures."""

    mix: Mixture | None  # None: crude MC
    who: dict[str, Any]  # ``Case``'s model, label, checkpoint, k, method
    ratio: bool = False
    log_r: list[np.ndarray] = field(default_factory=list)
    kinds: list[np.ndarray] = field(default_factory=list)
    perf: list[np.ndarray] = field(default_factory=list)
    components: list[int] = field(default_factory=list)
    cases: list[Case] = field(default_factory=list)
    started: int = 0
    places: np.ndarray | None = None  # (chain, 1 + kinds) lane changes, failures per place

    @property
    def drawn(self) -> Mixture | None:
        """The mixture at the shares its chunks so far were drawn in (the balance heuristic's,
        for an estimate unbiased whatever they are)."""
        return self.mix and self.mix.drawn(self.components)

    @property
    def lane_changes(self) -> int:
        return int(sum(a.sum() for a in self.perf))

    def add(self, out: dict, lo: int, keys: np.ndarray, dt: float, component: int) -> None:
        """A chunk's cases (``component``: the one that drew them, -1 the traffic's own; a
        chained chunk's lane changes one case's chain after another's, ``program``)."""
        perf, k, n = out["performed"][0], kinds(out, dt), len(keys)
        keep = np.ones_like(perf) if self.ratio else perf
        self.components.append(component)
        log_r, log_w, prop = np.zeros((perf.size, 0)), np.zeros(perf.size), None
        if self.mix is not None:
            log_r = Record.unpack(out["tilt"][0].astype(np.float64)).log_r
            log_w, prop = self.drawn.log_weights(log_r), self.drawn.to_dict()  # as replayed
        self.log_r.append(log_r[keep])
        self.kinds.append(k[keep] & perf[keep, None])
        self.perf.append(perf[keep])
        for c in np.nonzero(perf & k[:, 0])[0]:
            hit = [name for name, h in zip(KINDS, k[c], strict=True) if h]
            reason = OUTCOMES[int(out["reason"][0][c])]
            at, i = divmod(int(c), n)  # its place in the chain, its case
            key = [int(x) for x in keys[i]]
            case = Case(
                lo + i, key, float(log_w[c]), hit, reason, component, prop, **self.who, chain=at
            )
            self.cases.append(case)
        self.cases.sort(key=lambda r: -r.log_w)
        del self.cases[CASE_CAP:]
        self.started += perf.size
        if perf.size > n:  # chained: (chain, n) lane changes, each place's counts
            hits = (k & perf[:, None]).reshape(-1, n, len(KINDS)).sum(axis=1)
            counts = np.column_stack([perf.reshape(-1, n).sum(axis=1), hits])
            self.places = counts if self.places is None else self.places + counts

    def estimates(self) -> dict[str, rare.Estimate]:
        """Per kind: crude MC's, IS's or (``ratio``) IS's ratio estimate of the lane changes so
        far."""
        if not self.kinds:
            return {}
        k = np.concatenate(self.kinds)
        if self.mix is None:
            return {
                n: rare.mc_estimate(int(k[:, i].sum()), k.shape[0]) for i, n in enumerate(KINDS)
            }
        log_w = self.drawn.log_weights(np.concatenate(self.log_r))
        if self.ratio:
            perf = np.concatenate(self.perf)
            return {n: rare.is_ratio_estimate(log_w, perf, k[:, i]) for i, n in enumerate(KINDS)}
        return {n: rare.is_estimate(log_w, k[:, i]) for i, n in enumerate(KINDS)}


@dataclass(frozen=True)
class Settings:
    """What ``estimate`` does (``python -m jaxlc.validate``'s options)."""

    method: str = "is"  # "mc" or "is"
    kind: str = "collision"  # the failure kind the fit and the stop read (KINDS)
    family: str = "single"  # IS: one CE proposal, or the one-role tilts ("mixture")
    window: str = "acceptance"  # IS: where the braking's tilt starts (proposal.WINDOWS)
    defensive: float = 0.2  # IS: the nominal's share of the chunks
    lane_changes: int = 1_000_000  # at most, per model
    rel_halfwidth: float = 0.0  # stop once the kind's reaches it (0: never)
    chunk: int = 2048
    seed: int = 0
    max_steps: int = config.EvalConfig().max_steps
    chain: int = 1  # mc: lane changes per case, in one traffic (``program``)


def check_chain(method: str, chain: int) -> None:
    """``EvalError`` in one sentence where a method other than crude MC is asked to chain."""
    if chain > 1 and method != "mc":
        raise EvalError(f"--chain {chain}: only crude MC (--method mc) chains lane changes")


def check(cfg: config.Config, s: Settings) -> Settings:
    """``s`` where the traffic allows it; else ``EvalError`` in one sentence."""
    check_chain(s.method, s.chain)
    if s.method == "is" and s.family == "mixture":
        if not (cfg.env.braking and value_range(cfg.env.braking_rate)[1] > 0):
            raise EvalError(
                "--family mixture tilts braking events, and this traffic has none "
                "(--traffic env.braking=true, env.braking_rate > 0)"
            )
    return s


@dataclass
class Result:
    """One policy's validation: the fitted proposal and its pilot rounds, the estimates per
    kind, the counts and times, and the failures kept."""

    meta: dict[str, Any]
    method: str
    proposal: dict[str, Any] | None
    defensive: float
    ce: list[dict[str, Any]]
    estimates: dict[str, rare.Estimate]
    lane_changes: int
    cases_started: int  # with --chain L: places, L per case (lane-change slots, not resets)
    ce_s: float
    wall_s: float
    lane_changes_per_s: float
    interrupted: bool
    cases: list[Case] = field(default_factory=list)
    places: list[list[int]] | None = None  # chained: per place, lane changes, kinds' failures


def unlike_places(places: np.ndarray, kind: str) -> float:
    """P-value of a chi-squared test that the chain's places fail ``kind`` at one rate: a
    small one says the traffic changes along the chain (its warm-up too short to settle), so
    chained lane changes are not the independent cases' (docs/decisions.md); NaN with none."""
    failed = places[:, 1 + KINDS.index(kind)]
    table = np.stack([failed, places[:, 0] - failed])
    if not (table.sum(axis=0).all() and table.sum(axis=1).all()):
        return float("nan")
    return float(scipy.stats.chi2_contingency(table)[1])


def fit(base: EnvParams, run: Callable, pol: Policies, s: Settings) -> tuple[Mixture | None, list]:
    """The proposal the estimate draws from and the fit's record of each pilot round: none
    (``mc``), the CE's mixture of one or the pilots' one-role tilts (``is``)."""
    if s.method == "mc":
        return None, []
    col, log = KINDS.index(s.kind), tqdm.write

    def failed(out: dict) -> np.ndarray:  # (cases,) the failures of the kind
        return kinds(out, base.dt)[:, col]

    if s.family == "mixture":
        start = mixture.start_pilots(base, s.defensive, s.window, s.max_steps)
        return mixture.fit_pilots(run, pol, base, start, s.chunk, failed, seed=s.seed, log=log)
    start = dataclasses.replace(mixture.start_ce(base, s.defensive), window=s.window)
    ce_score = functools.partial(score, kind=s.kind)
    return mixture.fit_ce(run, pol, base, start, s.chunk, failed, ce_score, seed=s.seed, log=log)


def estimate(
    cfg: config.Config, actor: Any | None, k: int, meta: dict, s: Settings, model: int = 0
) -> Result:
    """The validation of policy ``model`` (``actor`` None: the scripted controller): the
    proposal (``is``), then chunks until the lane changes or the relative half-width are
    reached, or Ctrl-C."""
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    run, pol = program(cfg, s.max_steps, s.method == "is", s.chain), policies(cfg, actor, k)
    t0 = time.perf_counter()
    fitted, history = fit(base, run, pol, s)
    who = {"model": model, "label": meta["label"], "checkpoint": meta.get("checkpoint")}
    who |= {"k": meta.get("k") or 1, "method": s.method}
    tally = Tally(fitted, who, ratio=fitted is not None and s.window != "acceptance")
    lo, interrupted = 0, False
    bar = tqdm(total=s.lane_changes, unit="lc", desc=str(meta["label"]), leave=False)
    t1 = time.perf_counter()
    try:
        while tally.lane_changes < s.lane_changes:
            keys = streams.stream(s.seed, streams.VALIDATE, range(lo, lo + s.chunk))
            c = fitted.next_component(tally.components) if fitted else -1
            out = columns(jax.device_get(run(fitted and fitted.proposal(c), pol, keys))[0])
            before = tally.lane_changes
            tally.add(out, lo, np.asarray(keys), base.dt, c)
            lo += s.chunk
            bar.update(tally.lane_changes - before)
            est = tally.estimates()[s.kind]
            bar.set_postfix(p=f"{est.estimate:.3g}", rel=f"{est.rel_halfwidth:.3g}")
            if est.rel_halfwidth <= s.rel_halfwidth:
                break
    except KeyboardInterrupt:
        interrupted = True
    bar.close()
    t2 = time.perf_counter()
    drawn = tally.drawn
    if tally.places is not None and unlike_places(tally.places, s.kind) < 0.01:
        tqdm.write(f"{meta['label']}: {s.kind} differs along the chain (p < 0.01); see "
                   "validate.json's places, and prefer --chain 1 in this traffic")  # fmt: skip
    return Result(
        meta=meta,
        method=s.method,
        proposal=drawn and drawn.to_dict(),
        defensive=drawn.alpha if drawn else 0.0,
        ce=history,
        estimates=tally.estimates(),
        lane_changes=tally.lane_changes,
        cases_started=tally.started,
        ce_s=round(t1 - t0, 1),
        wall_s=round(t2 - t0, 1),
        lane_changes_per_s=round(tally.lane_changes / max(t2 - t1, 1e-9), 1),
        interrupted=interrupted,
        cases=tally.cases,
        places=None if tally.places is None else tally.places.tolist(),
    )
