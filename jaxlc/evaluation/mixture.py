"""IS's second proposal family (``python -m jaxlc.validate --family mixture``): a defensive
mixture of one-role braking tilts.

Component ``k`` is the traffic's own distribution but for role ``ROLES[k]``'s braking events
(``jaxlc.evaluation.proposal``), which start with probability ``rates[k]`` per step from the
window ``tilt_from``; the nominal itself is drawn in the share ``alpha``, component ``k`` in
``(1 - alpha) shares[k]``, whole chunks each. A lane change's weight is the balance heuristic
over every component, ``1 / (alpha + (1 - alpha) sum_k shares[k] q_k / p)``, at most
``1 / alpha``; each ``log p / q_k`` follows from the step statistics the program already
returns (``info["tilt"]``: a role's braking trials and events), so one program draws every
component and no ratio is recomputed in JAX. A failure that needs one role's braking weighs
little under that role's component however many draws of the other roles it made, where one
proposal tilting every role at once (``validation.fit_proposal``) multiplies their ratios.

``fit_mixture`` fits each role's rate by cross-entropy on pilot rounds and keeps the shares
equal: fitted shares followed the pilots' few failures and starved roles crude MC's failures
need (docs/decisions.md, "the mixture of one-role tilts").
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

from jaxlc.evaluation import rare, validation
from jaxlc.evaluation.cases import Policies, columns
from jaxlc.evaluation.proposal import ROLES, STATS, TILT_FROM, Proposal, nominal
from jaxlc.sim.braking import start_probability
from jaxlc.sim.env import EnvParams

RATE_FLOOR = 0.001  # per-step braking probability of a component at least (docs/decisions.md)
POOL_STOP = 150  # the fit stops once this many failures are pooled
# The nominal's share of the estimate's chunks (``--defensive``'s default with this family):
# each component already bounds the weight of a path without its role's braking
# (docs/decisions.md)
DEFENSIVE_SHARE = 0.05
_COL = {name: i for i, name in enumerate(STATS)}


@dataclass(frozen=True)
class Mixture:
    """Rates ``(K,)`` and shares ``(K,)`` of the one-role tilts of ``ROLES``, the nominal's
    share ``alpha``, the braking window ``tilt_from`` (a ``TILT_FROM`` name)."""

    p_fire: float  # the traffic's per-step probability of a braking event
    rates: tuple[float, ...]
    shares: tuple[float, ...]
    alpha: float
    tilt_from: str

    def component(self, p: EnvParams, k: int) -> Proposal:
        """Component ``k``'s proposal; ``k = -1``: the traffic's own draws (weighed against
        the mixture by ``log_weight``, not by the program)."""
        q = nominal(p).replace(tilt_from=jnp.float32(TILT_FROM.index(self.tilt_from)))
        if k < 0:
            return q.replace(drawn_nominal=jnp.float32(1.0))
        return q.replace(brake=q.brake.at[k].set(self.rates[k]))

    def log_ratios(self, stats: np.ndarray) -> np.ndarray:
        """``(n, K)`` ``log p / q_k`` of lane changes with step statistics ``stats``
        ``(n, len(STATS))``."""
        p = self.p_fire
        cols = []
        for role, q in zip(ROLES, self.rates, strict=True):
            ev = stats[:, _COL[f"brake_events_{role}"]].astype(np.float64)
            tr = stats[:, _COL[f"brake_trials_{role}"]].astype(np.float64)
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
            rates=tuple(map(float, d["rates"])),
            shares=tuple(map(float, d["shares"])),
            alpha=float(d["alpha"]),
            tilt_from=str(d["tilt_from"]),
        )


def start(p: EnvParams, alpha: float, tilt_from: str) -> Mixture:
    """The fit's start: every role's braking ``validation.START_BRAKE`` per step, equal
    shares."""
    n, p_fire = len(ROLES), float(start_probability(p))
    rates = (max(validation.START_BRAKE, p_fire),) * n
    return Mixture(p_fire, rates, (1.0 / n,) * n, alpha, tilt_from)


def fit_mixture(
    run: Callable,
    pol: Policies,
    p: EnvParams,
    start: Mixture,
    chunk: int,
    *,
    kind: str = "collision",
    rounds: int = 6,
    seed: int = 0,
    log: Callable = print,
) -> tuple[Mixture, list[dict[str, Any]]]:
    """Cross-entropy from ``start``: each round draws one pilot chunk per component (the
    CE's key stream, ``validation.PILOT_TAG``), pools its lane changes of ``kind``, each
    weighed by ``p / q`` of the round's draw (every component equally likely), and sets
    each role's rate to the pool's weighted events over its weighted trials, within
    ``[max(p, RATE_FLOOR), validation.BRAKE_MAX]``; the shares stay equal. Stops once
    ``POOL_STOP`` failures are pooled; with none, the start stands. Returns the mixture and
    each round's record."""
    mix, history, pool_st, pool_w = start, [], [], []
    col, n_comp = validation.KINDS.index(kind), len(ROLES)
    lo = max(start.p_fire, RATE_FLOOR)
    for r in range(rounds):
        failures = lane_changes = 0
        for k in range(n_comp):
            keys = validation.validate_keys(
                seed, validation.PILOT_TAG, (r * n_comp + k) * chunk, chunk
            )
            out = columns(jax.device_get(run(mix.component(p, k), pol, keys)[0]))
            perf = out["performed"][0]
            failed = validation.kinds(out, p.dt)[:, col] & perf
            st = out["tilt"][0][failed].astype(np.float64)
            # the round's draw: each component one chunk, so its q / p is their mean
            pool_w.append(1.0 / np.mean(np.exp(-mix.log_ratios(st)), axis=1))
            pool_st.append(st)
            failures, lane_changes = failures + int(failed.sum()), lane_changes + int(perf.sum())
        w, st = np.concatenate(pool_w), np.concatenate(pool_st)
        if w.size:
            rates = [
                rare.ce_rate(
                    w,
                    st[:, _COL[f"brake_events_{x}"]],
                    st[:, _COL[f"brake_trials_{x}"]],
                    lo,
                    validation.BRAKE_MAX,
                )
                for x in ROLES
            ]
            mix = dataclasses.replace(mix, rates=tuple(rates))
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
            f"CE round {r}: {failures} {kind} in {lane_changes} lane changes ({w.size} "
            f"pooled), rates {np.round(mix.rates, 5).tolist()}"
        )
        if w.size >= POOL_STOP:
            break
    return mix, history
