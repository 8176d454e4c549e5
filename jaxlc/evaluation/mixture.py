"""IS's second proposal family (``python -m jaxlc.validate --family mixture``): a defensive
mixture of one-role braking tilts.

Component ``k`` is the traffic's own distribution but for role ``ROLES[k]``'s braking, drawn
conditioned on the role's first event falling within its first ``horizons[k]`` braking trials
from the window ``tilt_from`` (``proposal.first_event_hazard``: every such path's ratio
``q_k / p`` is the same, ``1 / (1 - (1 - p)^H)``, wherever its event falls); the nominal
itself is drawn in the share ``alpha``, component ``k`` in ``(1 - alpha) shares[k]``, whole
chunks each. A lane change's weight is the balance heuristic over every component,
``1 / (alpha + (1 - alpha) sum_k shares[k] q_k / p)``, at most ``1 / alpha``; each
``log p / q_k`` is a statistic the program returns (``info["tilt"]``'s ``cond_`` column), so
one program draws every component. A failure that needs one role's braking weighs little under
that role's component however many draws of the other roles it made, where one proposal
tilting every role at once (``validation.fit_proposal``) multiplies their ratios.

``fit_mixture`` sets each horizon to the most braking trials of the role any pilot lane change
held, and the shares to ``sqrt(reach_k (m_k + SHARE_PRIOR))``: ``reach_k`` the traffic's
probability of an event within the horizon, ``m_k`` the pilots' weighted share of failures with
an event of role ``k`` (docs/decisions.md, "the mixture of one-role tilts"). A mixture of
constant-rate tilts (``rates``: each role's events ``rates[k]`` per step, no ``horizons``) is
what ``--family mixture`` drew before; it is still read and weighed, for the runs it made.
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
from jaxlc.evaluation import validation
from jaxlc.evaluation.cases import Policies, columns
from jaxlc.evaluation.proposal import COND, EVENTS, ROLES, TILT_FROM, TRIALS, Proposal, nominal
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import EnvParams

PILOT_ROUNDS = 2  # each one pilot chunk per component
# The shares' prior: each role counts as braking in this share of the failures more than the
# pilots saw, so a role none of their few failures braked in keeps a share
SHARE_PRIOR = 1.0 / len(ROLES)
# The nominal's share of the estimate's chunks (``--defensive``'s default with this family):
# each component already bounds the weight of a path without its role's braking
# (docs/decisions.md)
DEFENSIVE_SHARE = 0.05


@dataclass(frozen=True)
class Mixture:
    """The one-role tilts of ``ROLES``: their horizons ``(K,)`` (braking trials; or, for a
    mixture of constant-rate tilts, their ``rates`` ``(K,)`` per step) and shares ``(K,)``, the
    nominal's share ``alpha``, the braking window ``tilt_from`` (a ``TILT_FROM`` name)."""

    p_fire: float  # the traffic's per-step probability of a braking event
    rates: tuple[float, ...]  # () with ``horizons``
    shares: tuple[float, ...]
    alpha: float
    tilt_from: str
    horizons: tuple[float, ...] = ()

    def component(self, p: EnvParams, k: int) -> Proposal:
        """Component ``k``'s proposal; ``k = -1``: the traffic's own draws (weighed against
        the mixture by ``log_weight``, not by the program)."""
        q = nominal(p).replace(tilt_from=jnp.float32(TILT_FROM.index(self.tilt_from)))
        if self.horizons:  # every component's ratio is a statistic of every chunk
            q = q.replace(horizon=jnp.asarray(self.horizons, jnp.float32))
        if k < 0:
            return q.replace(drawn_nominal=jnp.float32(1.0))
        if self.horizons:
            return q.replace(conditional=q.conditional.at[k].set(1.0))
        return q.replace(brake=q.brake.at[k].set(self.rates[k]))

    def log_ratios(self, stats: np.ndarray) -> np.ndarray:
        """``(n, K)`` ``log p / q_k`` of lane changes with step statistics ``stats``
        ``(n, len(STATS))`` (+inf where component ``k`` cannot draw the lane change)."""
        stats = np.asarray(stats, np.float64)
        if self.horizons:
            return stats[:, COND]
        p, cols = self.p_fire, []
        for q, e, t in zip(self.rates, EVENTS, TRIALS, strict=True):
            ev, tr = stats[:, e], stats[:, t]
            cols.append(ev * math.log(p / q) + (tr - ev) * (math.log1p(-p) - math.log1p(-q)))
        return np.stack(cols, axis=1)

    def log_weight(self, stats: np.ndarray) -> np.ndarray:
        """``(n,)`` log weight of each lane change under the defensive mixture."""
        return self.log_weight_of(self.log_ratios(stats))

    def log_weight_of(self, log_r: np.ndarray) -> np.ndarray:
        """``(n,)`` log weights from ``log_ratios``' ``(n, K)``."""
        with np.errstate(divide="ignore"):  # a share of 0, or no tilted chunk
            mix = np.log(np.asarray(self.shares)) - log_r  # log shares[k] q_k / p
            tilted = np.log1p(-self.alpha) + np.logaddexp.reduce(mix, axis=1)
            alpha = math.log(self.alpha) if self.alpha > 0 else -math.inf
        return -np.logaddexp(alpha, tilted)

    def drawn(self, components: list[int]) -> Mixture:
        """This mixture with the shares of chunks drawn by ``components`` (-1: the
        nominal), each chunk's component."""
        c = np.asarray(components)
        n_tilted = int((c >= 0).sum())
        shares = (
            [int((c == k).sum()) / n_tilted for k in range(len(ROLES))] if n_tilted else self.shares
        )
        return dataclasses.replace(self, alpha=float((c < 0).mean()), shares=tuple(shares))

    def next_component(self, components: list[int]) -> int:
        """The next chunk's component (-1: the nominal) after chunks drawn by ``components``:
        whichever is furthest below its share, so the shares hold at every chunk."""
        target = np.concatenate([[self.alpha], (1 - self.alpha) * np.asarray(self.shares)])
        counts = np.bincount(np.asarray(components, int) + 1, minlength=target.size)
        return int(np.argmax(target * (len(components) + 1) - counts)) - 1

    def to_dict(self) -> dict[str, Any]:
        return {
            "family": "mixture",
            "roles": list(ROLES),
            "horizons": list(self.horizons),
            "rates": list(self.rates),
            "shares": list(self.shares),
            "alpha": self.alpha,
            "tilt_from": self.tilt_from,
            "p_fire": self.p_fire,
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Mixture:
        return cls(
            p_fire=float(d["p_fire"]),
            rates=tuple(map(float, d["rates"] if not d.get("horizons") else ())),
            shares=tuple(map(float, d["shares"])),
            alpha=float(d["alpha"]),
            tilt_from=str(d["tilt_from"]),
            horizons=tuple(map(float, d.get("horizons", ()))),
        )


def start(p: EnvParams, alpha: float, tilt_from: str, horizon: int) -> Mixture:
    """The fit's start: every role's horizon ``horizon`` trials (the case's step cap: a
    near role's vehicle brakes at most once a step), equal shares."""
    n = len(ROLES)
    return Mixture(
        float(start_probability(p)), (), (1.0 / n,) * n, alpha, tilt_from, (float(horizon),) * n
    )


def reach(horizons: np.ndarray, p_fire: float) -> np.ndarray:
    """``(K,)`` the traffic's probability of a braking event within each role's horizon."""
    return -np.expm1(np.asarray(horizons, np.float64) * math.log1p(-p_fire))


def fitted_shares(
    w: np.ndarray, stats: np.ndarray, horizons: np.ndarray, p_fire: float
) -> tuple[float, ...]:
    """``(K,)`` shares ``∝ sqrt(reach_k (m_k + SHARE_PRIOR))`` from failures with weights
    ``w`` ``(n,)`` and statistics ``stats`` ``(n, len(STATS))``: ``m_k`` the weighted share
    of them with an event of role ``k``. Were each failure to need one role's event, the
    mixture's variance would be ``sum_k m_k reach_k / shares_k`` (each failure weighs
    ``reach_k / shares_k``), least at these shares with ``SHARE_PRIOR = 0``; the prior keeps a
    role the few pilot failures missed from starving."""
    events = np.asarray(stats)[:, EVENTS] > 0
    m = (w[:, None] * events).sum(axis=0) / w.sum() if w.size else np.zeros(len(ROLES))
    s = np.sqrt(reach(horizons, p_fire) * (m + SHARE_PRIOR))
    return tuple(float(x) for x in s / s.sum())


def fit_mixture(
    run: Callable,
    pol: Policies,
    p: EnvParams,
    start: Mixture,
    chunk: int,
    *,
    kind: str = "collision",
    rounds: int = PILOT_ROUNDS,
    seed: int = 0,
    log: Callable = print,
) -> tuple[Mixture, list[dict[str, Any]]]:
    """Pilot rounds from ``start``: each draws one chunk per component (the CE's key stream,
    ``keys.PILOT``); after it, each role's horizon is the most braking trials of the
    role a pilot lane change held so far (a path with more, no event of the role's, is one its
    component cannot draw), and the shares are ``fitted_shares`` of the pooled lane changes of
    ``kind``, each weighed by ``p / q`` of its round's draw (every component equally likely).
    Returns the mixture and each round's record."""
    mix, history, pool_st, pool_w = start, [], [], []
    col, n_comp = validation.KINDS.index(kind), len(ROLES)
    most = np.zeros(n_comp)
    for r in range(rounds):
        failures = lane_changes = 0
        for k in range(n_comp):
            lo = (r * n_comp + k) * chunk
            keys = streams.stream(seed, streams.PILOT, range(lo, lo + chunk))
            out = columns(jax.device_get(run(mix.component(p, k), pol, keys)[0]))
            perf = out["performed"][0]
            st = out["tilt"][0].astype(np.float64)
            most = np.maximum(most, st[perf][:, TRIALS].max(axis=0, initial=0.0))
            failed = validation.kinds(out, p.dt)[:, col] & perf
            # the round's draw: each component one chunk, so its q / p is their mean
            pool_w.append(1.0 / np.mean(np.exp(-mix.log_ratios(st[failed])), axis=1))
            pool_st.append(st[failed])
            failures, lane_changes = failures + int(failed.sum()), lane_changes + int(perf.sum())
        w, st = np.concatenate(pool_w), np.concatenate(pool_st)
        horizons = np.maximum(most, 1.0)
        shares = fitted_shares(w, st, horizons, mix.p_fire)
        mix = dataclasses.replace(mix, horizons=tuple(horizons.tolist()), shares=shares)
        history.append(
            {
                "round": r,
                "failures": failures,
                "lane_changes": lane_changes,
                "pooled_failures": int(w.size),
                "mixture": mix.to_dict(),
            }
        )
        log(
            f"pilot round {r}: {failures} {kind} in {lane_changes} lane changes ({w.size} "
            f"pooled), horizons {horizons.astype(int).tolist()}, shares "
            f"{np.round(shares, 3).tolist()}"
        )
    return mix, history
