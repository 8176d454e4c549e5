"""A policy's failure probability per lane change, by crude Monte Carlo or importance sampling
(``python -m jaxlc.validate`` is its command line).

A lane change is a held-out case (``jaxlc.evaluation.cases``: reset, the approach, then the
manoeuvre; its warm-up steps the traffic alone, ``env.reset``'s ``traffic_only``), drawn from
a key stream of its own (``keys.stream(seed, VALIDATE, ...)``), in chunks of ``chunk``
cases: one jitted program (``program``) starts and rolls out a chunk under a ``Proposal``
(``jaxlc.evaluation.proposal``; crude MC runs the simulator's own draws, no proposal), and
``kinds`` reads each lane change's failures from the held-out outcome: any failure, each
failed end (collision, out of bounds, timeout, unfinished) and each norm of
``jaxlc.evaluation.safety.NORMS`` violated. ``Tally`` keeps every lane change's log weight and
kinds (a few bytes each) and the failures with their keys, so the estimate
(``jaxlc.evaluation.rare``) and the worst cases can be read at any chunk, Ctrl-C included.
The IS proposal is fitted by ``fit_proposal``: multilevel cross-entropy on pilot chunks from a
key stream apart from the estimate's. A defensive mixture draws the share ``alpha`` of the
estimate's chunks (``nominal_chunk``) from the traffic's own distribution, their ratios still
taken against the proposal, and weighs every lane change by the balance heuristic
(``rare.defensive``): a failure the proposal makes rarer than the traffic does weighs at most
``1 / alpha``.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc import config
from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import rare
from jaxlc.evaluation.cases import Policies, columns, init_actor, make_rollout, make_start_cases
from jaxlc.evaluation.heldout import lane_change_measures
from jaxlc.evaluation.proposal import (
    ROLES,
    STATS,
    Proposal,
    TiltedEnv,
    nominal,
)
from jaxlc.evaluation.results import OUTCOMES
from jaxlc.evaluation.safety import NORMS
from jaxlc.learn.networks import make_networks
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import EnvParams, action_dim

ENDS = ("collision", "out_of_bounds", "timeout", "unfinished")
KINDS = ("failure", *ENDS, *(f"norm_{name}" for name, *_ in NORMS))
CASE_CAP = 1000  # failures kept per model and kind, highest weight first
DEFENSIVE_SHARE = 0.2  # the estimate's share of chunks drawn from the nominal (docs/decisions.md)
POOL_STOP = 40  # the CE stops once this many failures of its kind are pooled
SMOOTH = 0.7  # the CE's step: new = SMOOTH * fitted + (1 - SMOOTH) * old
BRAKE_MAX = 0.05  # per-step probability of a braking event at most (one in 2 s)


@functools.lru_cache(maxsize=4)
def program(cfg: config.Config, max_steps: int, tilted: bool) -> Callable:
    """Jitted ``(proposal, policies, keys (chunk, 2)) -> (Outcome, Trace, Cases.performed)``
    of one policy on a chunk of cases (the first traced); ``tilted=False``: the simulator's own
    draws (the proposal is ignored, no log weight is computed)."""
    base = EnvParams.from_config(cfg.env, gamma=cfg.ddpg.gamma)
    actor_net, _ = make_networks(cfg.ddpg, action_dim(cfg.env))

    def run(prop: Proposal, pol: Policies, keys: jax.Array) -> tuple:
        env = TiltedEnv(prop) if tilted else None
        cs = make_start_cases(base, max_steps, env, traffic_warmup=True)(keys)
        out, trace = make_rollout(base, actor_net.apply, max_steps, env)(
            pol, cs, jnp.zeros(1, jnp.int32)
        )
        return out, trace

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
class Tally:
    """What the chunks so far found, per performed lane change."""

    log_w: list[np.ndarray] = field(default_factory=list)
    kinds: list[np.ndarray] = field(default_factory=list)
    cases: list[dict[str, Any]] = field(default_factory=list)
    started: int = 0  # cases started (performed or not)
    ratio: bool = False  # the proposal tilts before acceptance: keep every case, ratio estimate
    perf: list[np.ndarray] = field(default_factory=list)
    nominal_started: int = 0  # cases of chunks drawn from the nominal (``drawn_nominal``)
    # ``--family mixture`` (``jaxlc.evaluation.mixture.Mixture``): each case's weight from its
    # log ratios to the components (``log_r``) and the shares the chunks were drawn in
    mixture: Any = None
    log_r: list[np.ndarray] = field(default_factory=list)
    components: list[int] = field(default_factory=list)  # each chunk's (-1: the nominal)

    def add(
        self,
        out: dict,
        lo: int,
        keys: np.ndarray,
        dt: float,
        tilted: bool,
        nominal: bool = False,
        component: int = -1,
        drawn: dict[str, Any] | None = None,
    ) -> None:
        """A chunk's cases (``nominal``: drawn from the traffic's own distribution, their log
        ratios taken against the proposal: the defensive mixture's share). With a mixture:
        the ``component`` that drew them; ``drawn``: what each failure records of its
        proposal."""
        perf = out["performed"][0]
        k = kinds(out, dt)
        keep = np.ones_like(perf) if self.ratio else perf
        drawn = {"drawn_nominal": nominal, **(drawn or {})}
        if self.mixture is not None:
            self.components.append(component)
            mix = self.drawn_mixture
            log_r = self.mixture.log_ratios(out["tilt"][0])
            log_w = mix.log_weight_of(log_r)  # the shares so far: the case's replay gives it
            self.log_r.append(log_r[keep])
            drawn["mixture"] = mix.to_dict()
        else:
            log_w = out["log_w"][0].astype(np.float64) if tilted else np.zeros(perf.shape)
            self.log_w.append(log_w[keep])
        self.kinds.append(k[keep] & perf[keep, None])
        self.perf.append(perf[keep])
        for c in np.nonzero(perf & k[:, 0])[0]:
            self.cases.append(
                {
                    "index": lo + int(c),
                    "key": [int(x) for x in keys[c]],
                    "log_w": float(log_w[c]),
                    "kinds": [n for n, hit in zip(KINDS, k[c], strict=True) if hit],
                    "reason": OUTCOMES[int(out["reason"][0][c])],
                    **drawn,
                }
            )
        self.cases.sort(key=lambda r: -r["log_w"])
        del self.cases[CASE_CAP:]
        self.started += perf.size
        self.nominal_started += perf.size if nominal else 0

    @property
    def drawn_mixture(self) -> Any:
        """The mixture with the shares its chunks so far were drawn in (the balance
        heuristic's, for an estimate unbiased whatever they are)."""
        return self.mixture.drawn(self.components)

    @property
    def defensive(self) -> float:
        """The share of the cases drawn from the nominal (0: the proposal's alone)."""
        return self.nominal_started / self.started if self.started else 0.0

    @property
    def lane_changes(self) -> int:
        return int(sum(a.sum() for a in self.perf))

    def estimates(self, method: str) -> dict[str, dict[str, Any]]:
        """Per kind: ``rare.mc_estimate`` or ``rare.is_estimate`` of the lane changes so far."""
        if not self.kinds:
            return {}
        k = np.concatenate(self.kinds)
        if self.mixture is not None:
            log_w = self.drawn_mixture.log_weight_of(np.concatenate(self.log_r))
        else:
            log_w = np.concatenate(self.log_w)
        if self.nominal_started and self.mixture is None:  # the balance heuristic
            log_w = rare.defensive(log_w, self.defensive)
        if method == "mc":
            return {
                n: rare.mc_estimate(int(k[:, i].sum()), k.shape[0]) for i, n in enumerate(KINDS)
            }
        if self.ratio:
            perf = np.concatenate(self.perf)
            return {n: rare.is_ratio_estimate(log_w, perf, k[:, i]) for i, n in enumerate(KINDS)}
        return {n: rare.is_estimate(log_w, k[:, i]) for i, n in enumerate(KINDS)}


def nominal_chunk(index: int, alpha: float) -> bool:
    """Whether the estimate's chunk ``index`` is drawn from the nominal: the share ``alpha``
    of the chunks, spread evenly (chunk 0 is the proposal's)."""
    return math.floor((index + 1) * alpha) > math.floor(index * alpha)


START_BRAKE = 0.005  # the CE's first proposal: a braking event per role one in 20 s


def start_proposal(p: EnvParams) -> Proposal:
    """The CE's start: the nominal, braking events around the ego ``START_BRAKE`` per step."""
    nom = nominal(p)
    return nom.replace(brake=jnp.maximum(nom.brake, START_BRAKE))


def _fit(w: np.ndarray, st: np.ndarray, p_fire: float) -> Proposal:
    """The CE's fit of a proposal to the elite's weights ``w`` and statistics ``st``."""
    s = {n: st[:, i] for i, n in enumerate(STATS)}
    events = sum(s[f"brake_events_{x}"] for x in ROLES)
    brake = [
        rare.ce_rate(w, s[f"brake_events_{x}"], s[f"brake_trials_{x}"], p_fire, BRAKE_MAX)
        for x in ROLES
    ]
    return Proposal(
        brake=jnp.asarray(brake, jnp.float32),
        brake_acc=jnp.float32(rare.ce_theta(w, s["brake_acc_sum"], events)),
        brake_time=jnp.float32(rare.ce_theta(w, s["brake_time_sum"], events)),
        yields=jnp.float32(rare.ce_rate(w, s["yield_events"], s["yield_trials"], 0.05, 0.95)),
    )


def fit_proposal(
    run: Callable,
    pol: Policies,
    p: EnvParams,
    start: Proposal,
    chunk: int,
    *,
    kind: str = "collision",
    rounds: int = 6,
    seed: int = 0,
    log: Callable = print,
) -> tuple[Proposal, list[dict[str, Any]]]:
    """Multilevel cross-entropy from ``start``: each round runs a pilot chunk and moves the
    proposal ``SMOOTH`` of the way to its elite's weighted fit. The elite: every lane change
    of ``kind`` of the rounds so far (each weighted by its ratio to the traffic's own
    distribution, so rounds under different proposals pool) once ``rare.MIN_ELITE`` are seen;
    short of them, the proposal is held for another round where as many failures again would
    make them, else the elite is the round's tenth closest to failing so (``score``), whose
    ``level`` the record gives (``None`` for a held round). Stops once ``POOL_STOP``
    failures are pooled. Returns the proposal and each round's record."""
    prop, history, col = start, [], KINDS.index(kind)
    p_fire = float(start_probability(p))
    pool: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []
    for r in range(rounds):
        keys = streams.stream(seed, streams.PILOT, range(r * chunk, (r + 1) * chunk))
        out = columns(jax.device_get(run(prop, pol, keys)[0]))
        perf = out["performed"][0]
        failed = kinds(out, p.dt)[perf, col]
        pool.append((out["log_w"][0][perf], failed, out["tilt"][0][perf].astype(np.float64)))
        log_w, hits, st = (np.concatenate(a) for a in zip(*pool, strict=True))
        # Failures short of an elite, but as many again would make one: another round under
        # the same proposal, not a step toward the tenth closest by ``score``, whose lane
        # changes need not share the failures' causes.
        held = hits.sum() < rare.MIN_ELITE <= hits.sum() + failed.sum() and r + 1 < rounds
        level = None
        if hits.sum() >= rare.MIN_ELITE:
            w, level = rare.elite(log_w, hits, np.zeros(hits.shape), rho=0.0)
        elif not held:
            log_w, st = pool[-1][0], pool[-1][2]
            w, level = rare.elite(log_w, failed, score(out, kind)[perf])
        if not held:
            fit = _fit(w, st, p_fire).replace(tilt_from=start.tilt_from)
            prop = jax.tree.map(lambda a, b: SMOOTH * a + (1 - SMOOTH) * b, fit, prop)
        history.append(
            {
                "round": r,
                "failures": int(failed.sum()),
                "lane_changes": int(perf.sum()),
                "pooled_failures": int(hits.sum()),
                "level": level,
                "proposal": prop.to_dict(),
            }
        )
        if held:
            elite = "held (as many failures again make one)"
        else:
            elite = "the failures" if level == math.inf else f"score >= {level:g}"
        log(
            f"CE round {r}: {int(failed.sum())} {kind} in {int(perf.sum())} lane changes "
            f"({int(hits.sum())} pooled), elite {elite}"
        )
        if hits.sum() >= POOL_STOP:
            break
    return prop, history
