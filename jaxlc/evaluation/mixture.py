"""A fitted proposal (``Mixture``): its ``proposal.Tilt`` components, how its chunks are
drawn, the one weighing of every lane change, and the two fits that make it.

The nominal draws the share ``alpha`` of the chunks, component ``k`` ``(1 - alpha)
shares[k]`` (``next_component``); a lane change weighs ``1 / (alpha + (1 - alpha) sum_k
shares[k] q_k / p)`` (``rare.balance``) at the shares its chunks were drawn in (``drawn``).
``fit_ce``: one proposal (a mixture of one) tilting every role, by multilevel cross-entropy.
``fit_pilots`` (``--family mixture``): one-role tilts, each drawing its role's first braking
event conditioned within a horizon (every such path weighs ``1 - (1 - p)^H`` to it), the
horizons and shares (``fitted_shares``) from pilot rounds (docs/decisions.md).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from jaxlc.evaluation import keys as streams
from jaxlc.evaluation import rare
from jaxlc.evaluation.cases import Policies, columns
from jaxlc.evaluation.proposal import ROLES, WINDOWS, Proposal, Record, Tilt, nominal, stack
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import EnvParams

# The nominal's share of the estimate's chunks (``--defensive``'s default), by family: the
# one-role tilts already bound the weight of a path without its role's braking
DEFENSIVE_SHARE = {"single": 0.2, "mixture": 0.05}
START_BRAKE = 0.005  # the CE's first proposal: a braking event per role one in 20 s
POOL_STOP = 40  # the CE stops once this many failures of its kind are pooled
SMOOTH = 0.7  # the CE's step: new = SMOOTH * fitted + (1 - SMOOTH) * old
BRAKE_MAX = 0.05  # per-step probability of a braking event at most (one in 2 s)
PILOT_ROUNDS = 2  # the one-role tilts': each one pilot chunk per component
# The shares' prior: each role counts as braking in this share of the failures more than the
# pilots saw, so a role none of their few failures braked in keeps a share
SHARE_PRIOR = 1.0 / len(ROLES)


@dataclass(frozen=True)
class Mixture:
    """The components ``tilts`` (leaves ``(K, ...)``), their ``shares`` of the tilted chunks,
    the nominal's share ``alpha``, the braking window (a ``WINDOWS`` name) and the family."""

    tilts: Tilt
    shares: tuple[float, ...]
    alpha: float
    window: str = "acceptance"
    family: str = "single"

    def proposal(self, drawn: int) -> Proposal:
        """The program's source of draws for a chunk drawn by component ``drawn`` (-1: the
        traffic's own, weighed against every component)."""
        return Proposal(self.tilts, jnp.int32(drawn), jnp.int32(WINDOWS[self.window]))

    def log_weights(self, log_r: np.ndarray) -> np.ndarray:
        """``(n,)`` log weight of each lane change from its log ratios ``(n, K)``: the
        balance heuristic (float64)."""
        return rare.balance(np.asarray(log_r, np.float64), self.shares, self.alpha)

    def next_component(self, components: list[int]) -> int:
        """The next chunk's component (-1: the nominal) after chunks drawn by ``components``:
        whichever is furthest below its share, so the shares hold at every chunk; a mixture of
        one gives the nominal chunk ``i`` where ``floor(i alpha)`` steps up (chunk 0 the
        proposal's, as the CE's estimates always drew)."""
        if len(self.shares) == 1:
            i = len(components)
            return -1 if math.floor((i + 1) * self.alpha) > math.floor(i * self.alpha) else 0
        target = np.concatenate([[self.alpha], (1 - self.alpha) * np.asarray(self.shares)])
        counts = np.bincount(np.asarray(components, int) + 1, minlength=target.size)
        return int(np.argmax(target * (len(components) + 1) - counts)) - 1

    def drawn(self, components: list[int]) -> Mixture:
        """This mixture at the shares chunks drawn by ``components`` hold."""
        c = np.asarray(components)
        tilted, shares = int((c >= 0).sum()), self.shares
        if tilted:
            shares = tuple(int((c == k).sum()) / tilted for k in range(len(shares)))
        alpha = float((c < 0).mean()) if c.size else self.alpha  # none drawn yet: as asked
        return dataclasses.replace(self, alpha=alpha, shares=shares)

    def to_dict(self) -> dict[str, Any]:
        tilts = {f.name: np.asarray(getattr(self.tilts, f.name)).tolist() for f in _FIELDS}
        return {"family": self.family, "roles": list(ROLES), "window": self.window} | {
            "alpha": self.alpha,
            "shares": list(self.shares),
            "tilts": tilts,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Mixture:
        tilts = Tilt(**{k: jnp.asarray(v, jnp.float32) for k, v in d["tilts"].items()})
        return cls(tilts, tuple(d["shares"]), d["alpha"], d["window"], d["family"])


_FIELDS = dataclasses.fields(Tilt)


def single(t: Tilt, alpha: float, window: str = "acceptance") -> Mixture:
    """One proposal, a mixture of one."""
    return Mixture(stack([t]), (1.0,), alpha, window)


def start_ce(p: EnvParams, alpha: float) -> Mixture:
    """The CE's start: the nominal, braking events around the ego ``START_BRAKE`` per step."""
    nom = nominal(p)
    return single(nom.replace(brake=jnp.maximum(nom.brake, START_BRAKE)), alpha)


def start_pilots(p: EnvParams, alpha: float, window: str, horizon: int) -> Mixture:
    """The pilots' start: every role's horizon ``horizon`` trials (the case's step cap: a near
    role's vehicle brakes at most once a step), equal shares."""
    n, nom = len(ROLES), nominal(p)
    h = jnp.full(n, float(horizon), jnp.float32)
    tilts = [nom.replace(horizon=h, conditional=jnp.eye(n, dtype=jnp.float32)[k]) for k in range(n)]
    return Mixture(stack(tilts), (1.0 / n,) * n, alpha, window, "mixture")


def reach(horizons: np.ndarray, p_fire: float) -> np.ndarray:
    """``(K,)`` the traffic's probability of a braking event within each role's horizon."""
    return -np.expm1(np.asarray(horizons, np.float64) * math.log1p(-p_fire))


def fitted_shares(
    w: np.ndarray, events: np.ndarray, horizons: np.ndarray, p_fire: float
) -> tuple[float, ...]:
    """``(K,)`` shares ``∝ sqrt(reach_k (m_k + SHARE_PRIOR))`` from failures with weights
    ``w`` ``(n,)`` and braking events ``(n, K)``: ``m_k`` the weighted share of them with an
    event of role ``k``. Were each failure to need one role's event, the mixture's variance
    would be ``sum_k m_k reach_k / shares_k`` (each failure weighs ``reach_k / shares_k``),
    least at these shares with ``SHARE_PRIOR = 0``; the prior keeps a role the few pilot
    failures missed from starving."""
    events = np.asarray(events) > 0
    m = (w[:, None] * events).sum(axis=0) / w.sum() if w.size else np.zeros(len(ROLES))
    s = np.sqrt(reach(horizons, p_fire) * (m + SHARE_PRIOR))
    return tuple(float(x) for x in s / s.sum())


def _pilot(run: Callable, mix: Mixture, k: int, pol: Policies, keys: Any) -> tuple:
    """``(out, performed (n,), Record of float64 (n, ...))`` of a pilot chunk drawn by ``k``."""
    out = columns(jax.device_get(run(mix.proposal(k), pol, keys)[0]))
    return out, out["performed"][0], Record.unpack(out["tilt"][0].astype(np.float64))


def fit_pilots(
    run: Callable, pol: Policies, p: EnvParams, start: Mixture, chunk: int, failed: Callable,
    *, rounds: int = PILOT_ROUNDS, seed: int = 0, log: Callable = print,
) -> tuple[Mixture, list[dict[str, Any]]]:  # fmt: skip
    """Pilot rounds from ``start``: each draws one chunk per component (``keys.PILOT``); after
    it, each horizon is the most braking trials of its role a pilot lane change held so far (a
    path with more, no event of the role's, is one its component cannot draw), and the shares
    are ``fitted_shares`` of the pooled lane changes that ``failed(out) -> (n,)`` marks, each
    weighed by ``p / q`` of its round's draw (every component equally likely). Returns the
    mixture and each round's record."""
    mix, history, pool_r, pool_e = start, [], [], []
    p_fire, n_comp = float(start_probability(p)), len(ROLES)
    most = np.zeros(n_comp)
    for r in range(rounds):
        failures = lane_changes = 0
        for k in range(n_comp):
            lo = (r * n_comp + k) * chunk
            out, perf, rec = _pilot(
                run, mix, k, pol, streams.stream(seed, streams.PILOT, range(lo, lo + chunk))
            )
            most = np.maximum(most, rec.trials[perf].max(axis=0, initial=0.0))
            hit = failed(out) & perf
            pool_r.append(rec.log_r[hit])
            pool_e.append(rec.events[hit])
            failures, lane_changes = failures + int(hit.sum()), lane_changes + int(perf.sum())
        # the round's draw: each component one chunk, so its q / p is their mean
        w = 1.0 / np.mean(np.exp(-np.concatenate(pool_r)), axis=1)
        horizons = np.maximum(most, 1.0)
        shares = fitted_shares(w, np.concatenate(pool_e), horizons, p_fire)
        h = jnp.broadcast_to(jnp.asarray(horizons, jnp.float32), mix.tilts.horizon.shape)
        mix = dataclasses.replace(mix, tilts=mix.tilts.replace(horizon=h), shares=shares)
        history.append(_round(r, failures, lane_changes, int(w.size), mix))
        log(
            f"pilot round {r}: {failures} failures in {lane_changes} lane changes ({w.size} "
            f"pooled), horizons {horizons.astype(int).tolist()}, shares "
            f"{np.round(shares, 3).tolist()}"
        )
    return mix, history


def _round(r: int, failures: int, lane_changes: int, pooled: int, mix: Mixture, **more) -> dict:
    """A fit's record of its round ``r``."""
    return (
        {"round": r, "failures": failures, "lane_changes": lane_changes}
        | more
        | {
            "pooled_failures": pooled,
            "proposal": mix.to_dict(),
        }
    )


def _ce_fit(w: np.ndarray, rec: Record, p_fire: float) -> Tilt:
    """The CE's fit of a tilt to the elite's weights ``w`` and statistics ``rec``."""
    events = rec.events.sum(axis=1)
    brake = [
        rare.ce_rate(w, rec.events[:, i], rec.trials[:, i], p_fire, BRAKE_MAX)
        for i in range(len(ROLES))
    ]
    zeros = jnp.zeros(len(ROLES), jnp.float32)
    return Tilt(
        brake=jnp.asarray(brake, jnp.float32),
        brake_acc=jnp.float32(rare.ce_theta(w, rec.acc_sum, events)),
        brake_time=jnp.float32(rare.ce_theta(w, rec.time_sum, events)),
        yields=jnp.float32(rare.ce_rate(w, rec.yield_events, rec.yield_trials, 0.05, 0.95)),
        horizon=zeros,
        conditional=zeros,
    )


def fit_ce(
    run: Callable, pol: Policies, p: EnvParams, start: Mixture, chunk: int, failed: Callable,
    score: Callable, *, rounds: int = 6, seed: int = 0, log: Callable = print,
) -> tuple[Mixture, list[dict[str, Any]]]:  # fmt: skip
    """Multilevel cross-entropy from ``start`` (a mixture of one): each round runs a pilot
    chunk and moves the tilt ``SMOOTH`` of the way to its elite's weighted fit. The elite:
    every lane change ``failed(out) -> (n,)`` marks, of the rounds so far (each weighted by its
    ratio to the traffic's own distribution, so rounds under different proposals pool) once
    ``rare.MIN_ELITE`` are seen; short of them, the proposal is held for another round where as
    many failures again would make them, else the elite is the round's tenth closest to
    failing (``score(out) -> (n,)``), whose ``level`` the record gives (``None`` for a held
    round). Stops once ``POOL_STOP`` failures are pooled. Returns the mixture and each
    round's record."""
    mix, history, p_fire = start, [], float(start_probability(p))
    pool: list[tuple[np.ndarray, np.ndarray]] = []
    for r in range(rounds):
        keys = streams.stream(seed, streams.PILOT, range(r * chunk, (r + 1) * chunk))
        out, perf, _ = _pilot(run, mix, 0, pol, keys)
        hit = failed(out)[perf]
        pool.append((out["tilt"][0][perf].astype(np.float64), hit))
        rec, hits = (np.concatenate(a) for a in zip(*pool, strict=True))
        # Failures short of an elite, but as many again would make one: another round under
        # the same proposal, not a step toward the tenth closest by ``score``, whose lane
        # changes need not share the failures' causes.
        held = hits.sum() < rare.MIN_ELITE <= hits.sum() + hit.sum() and r + 1 < rounds
        level = None
        if hits.sum() >= rare.MIN_ELITE:
            rec = Record.unpack(rec)
            w, level = rare.elite(rec.log_r[:, 0], hits, np.zeros(hits.shape), rho=0.0)
        elif not held:
            rec = Record.unpack(pool[-1][0])
            w, level = rare.elite(rec.log_r[:, 0], hit, score(out)[perf])
        if not held:
            fit = stack([_ce_fit(w, rec, p_fire)])
            tilts = jax.tree.map(lambda a, b: SMOOTH * a + (1 - SMOOTH) * b, fit, mix.tilts)
            mix = dataclasses.replace(mix, tilts=tilts)
        history.append(
            _round(r, int(hit.sum()), int(perf.sum()), int(hits.sum()), mix, level=level)
        )
        if held:
            elite = "held (as many failures again make one)"
        else:
            elite = "the failures" if level == math.inf else f"score >= {level:g}"
        log(
            f"CE round {r}: {int(hit.sum())} failures in {int(perf.sum())} lane changes "
            f"({int(hits.sum())} pooled), elite {elite}"
        )
        if hits.sum() >= POOL_STOP:
            break
    return mix, history
