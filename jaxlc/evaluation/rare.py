"""Rare-event estimators of a failure probability per lane change: crude Monte Carlo and
importance sampling (IS), and the cross-entropy (CE) updates.

Every random decision of the simulator is a uniform ``u`` in [0, 1), so a proposal changes
those alone (``jaxlc.evaluation.proposal``): an event ``u < p`` drawn with probability ``q``
(``tilt_bernoulli``, ratio ``p/q`` where it fires, ``(1-p)/(1-q)`` where not), a value ``lo + u
(hi - lo)`` with ``u`` from a truncated exponential (``tilt_exponential``, ratio ``1 /
density``); ``q = p`` and ``theta = 0`` give log ratios of exactly 0. A lane change's ratio is
the sum of its draws' logs; ``balance`` weighs it against a defensive mixture (at most ``1 /
alpha``). The IS estimate ``mean(w * failed)`` is unbiased for any proposal that can draw every
failure, its interval the normal one of the weighted sample, ``mean(w)`` (expectation 1) its
check; crude MC counts failures (Clopper-Pearson, ``jaxlc.evaluation.heldout``).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.stats
from jax import Array
from jax.scipy.special import logsumexp

from jaxlc.evaluation.heldout import clopper_pearson, upper_bound
from jaxlc.evaluation.stats import CONFIDENCE

Z = float(scipy.stats.norm.ppf(0.5 + CONFIDENCE / 2))  # 1.96
ONE_BELOW = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
THETA_MAX = 30.0  # |theta| of a truncated exponential tilt (mass ~e^-30 at the other end)
MIN_ELITE = 10  # failures enough for an elite of their own, whatever their share


def tilt_bernoulli(v: Array, p: Array, q: Array) -> Array:
    """The nominal uniform ``u`` drawn through the proposal's uniform ``v`` so that ``u < p``
    holds with probability ``q`` (``[0, p)`` gets the share ``q``)."""
    below = v < q
    u = jnp.where(below, v * (p / q), p + (v - q) * ((1.0 - p) / (1.0 - q)))
    return jnp.clip(u, 0.0, ONE_BELOW)


def bernoulli_log_ratio(u: Array, p: Array, q: Array) -> Array:
    """Log likelihood ratio, nominal / tilted to ``q``, of the event ``u < p`` as read."""
    return jnp.where(u < p, jnp.log(p) - jnp.log(q), jnp.log1p(-p) - jnp.log1p(-q))


def tilt_exponential(v: Array, theta: Array) -> Array:
    """``u`` from the truncated exponential of ``theta`` on [0, 1) (inverse CDF of the
    proposal's uniform ``v``); ``theta = 0``: ``u = v``."""
    flat = jnp.abs(theta) < 1e-6
    t = jnp.where(flat, 1.0, theta)
    return jnp.clip(jnp.where(flat, v, jnp.log1p(v * jnp.expm1(t)) / t), 0.0, ONE_BELOW)


def exponential_log_ratio(u: Array, theta: Array) -> Array:
    """``log(1 / density(u))`` of the truncated exponential of ``theta`` (0 at ``theta = 0``)."""
    flat = jnp.abs(theta) < 1e-6
    t = jnp.where(flat, 1.0, theta)
    return jnp.where(flat, 0.0, jnp.log(jnp.expm1(t) / t) - t * u)


def balance(log_r: Any, shares: Any, alpha: float) -> Any:
    """The log weight of a draw from the defensive mixture ``alpha nominal + (1 - alpha)
    sum_k shares[k] q_k`` (the balance heuristic; Hesterberg 1995), given ``log_r`` ``(...,
    K)``, its log ratios nominal / ``q_k``: ``-log(alpha + (1 - alpha) sum_k shares[k]
    e^-log_r_k)``, at most ``-log alpha``; ``alpha = 0`` and one component give ``log_r``
    itself. Numpy in (float64), numpy out; JAX in, JAX out."""
    if not isinstance(log_r, np.ndarray):
        mix = jnp.log(jnp.asarray(shares)) - log_r
        return -jnp.logaddexp(jnp.log(alpha), jnp.log1p(-alpha) + logsumexp(mix, axis=-1))
    with np.errstate(divide="ignore"):  # a share of 0
        mix = np.log(np.asarray(shares)) - log_r
        tilted = np.log1p(-alpha) + np.logaddexp.reduce(mix, axis=-1)
    return -np.logaddexp(math.log(alpha) if alpha > 0 else -math.inf, tilted)


def exponential_mean(theta: float) -> float:
    """Mean of the truncated exponential of ``theta`` on [0, 1)."""
    if abs(theta) < 1e-6:
        return 0.5
    return 1.0 / -math.expm1(-theta) - 1.0 / theta


def exponential_fit(mean: float) -> float:
    """The ``theta`` whose truncated exponential has this mean (its maximum likelihood fit),
    by bisection; clipped to ``THETA_MAX``."""
    lo, hi = -THETA_MAX, THETA_MAX
    mean = min(max(mean, exponential_mean(lo)), exponential_mean(hi))
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if exponential_mean(mid) < mean else (lo, mid)
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class Estimate:
    """A failure probability per lane change: the estimate, its 95% interval and one-sided
    upper bound, relative half-width, failures, effective sample size, lane changes; IS's
    also the mean weight with its interval (expectation 1)."""

    estimate: float
    lo: float
    hi: float
    upper_bound: float
    rel_halfwidth: float
    failures: int
    ess: float
    lane_changes: int
    mean_weight: float | None = None
    mean_weight_lo: float | None = None
    mean_weight_hi: float | None = None

    def to_dict(self) -> dict[str, Any]:
        return {k: v for k, v in dataclasses.asdict(self).items() if v is not None}


def mc_estimate(failures: int, n: int) -> Estimate:
    """Crude Monte Carlo: ``failures`` of ``n`` lane changes, Clopper-Pearson 95%."""
    lo, hi = clopper_pearson(failures, n)
    p = failures / n if n else math.nan
    half = 0.5 * (hi - lo)
    rel = half / p if p > 0 else math.inf
    return Estimate(p, lo, hi, upper_bound(failures, n), rel, int(failures), float(n), int(n))


def is_estimate(log_w: np.ndarray, failed: np.ndarray) -> Estimate:
    """Importance sampling from lane changes ``(n,)`` with log weights ``log_w`` and outcome
    ``failed``: ``mean(w * failed)``, its normal 95% interval from the weighted sample, the
    relative half-width, the effective sample size of the failures' weights (Kish:
    ``(sum y)^2 / sum y^2``) and the mean weight with its interval (expectation 1)."""
    log_w, failed = np.asarray(log_w, np.float64), np.asarray(failed, bool)
    n = log_w.size
    w = np.exp(log_w)
    y = np.where(failed, w, 0.0)
    p = float(y.mean()) if n else math.nan
    se = float(y.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    return _weighted(p, se, y, failed, n, w)


def _weighted(
    p: float, se: float, y: np.ndarray, failed: np.ndarray, lane_changes: int, w: np.ndarray
) -> Estimate:
    """The estimate ``p`` with standard error ``se``: ``y`` the failures' weighted terms (the
    ESS's), ``w`` every sample's weight (its mean's interval)."""
    n = w.size
    w_se = float(w.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    mean_w = float(w.mean()) if n else math.nan
    bound = p + float(scipy.stats.norm.ppf(CONFIDENCE)) * se if y.any() else math.nan
    rel, ess = Z * se / p if p > 0 else math.inf, y.sum() ** 2 / (y**2).sum() if y.any() else 0.0
    fails, mean = int(failed.sum()), (mean_w, mean_w - Z * w_se, mean_w + Z * w_se)
    lo = max(p - Z * se, 0.0)
    return Estimate(p, lo, p + Z * se, bound, rel, fails, float(ess), int(lane_changes), *mean)


def is_ratio_estimate(log_w: np.ndarray, perf: np.ndarray, failed: np.ndarray) -> Estimate:
    """IS per lane change when the proposal also changes which cases become lane changes
    (``--tilt-from entry``): ``sum(w f) / sum(w perf)`` over every case started (``failed``
    implies ``perf``), the delta method's normal 95% interval; consistent, not unbiased (its
    bias is O(1/n))."""
    log_w = np.asarray(log_w, np.float64)
    perf, failed = np.asarray(perf, bool), np.asarray(failed, bool) & np.asarray(perf, bool)
    w = np.exp(log_w)
    num, den = np.where(failed, w, 0.0), np.where(perf, w, 0.0)
    p = float(num.sum() / den.sum()) if den.sum() > 0 else math.nan
    se = float(np.sqrt(np.sum((num - p * den) ** 2)) / den.sum()) if den.sum() > 0 else math.nan
    return _weighted(p, se, num, failed, int(perf.sum()), w)


def elite(
    log_w: np.ndarray, failed: np.ndarray, score: np.ndarray, rho: float = 0.1
) -> tuple[np.ndarray, float]:
    """Multilevel CE's elite: ``(weights (n,), level)``: the failures when at least ``rho n``
    (or ``MIN_ELITE``) of the sample failed, else the ``rho`` share with the highest
    ``score`` (a failure scores +inf); each elite sample carries its likelihood ratio, the
    rest 0."""
    failed = np.asarray(failed, bool)
    s = np.where(failed, np.inf, np.asarray(score, np.float64))
    enough = failed.sum() >= min(rho * failed.size, MIN_ELITE)
    level = math.inf if enough or not failed.size else float(np.quantile(s, 1.0 - rho))
    chosen = s >= level
    w = np.where(chosen, np.exp(np.asarray(log_w, np.float64) - np.max(log_w)), 0.0)
    return w, level


def ce_rate(w: np.ndarray, events: np.ndarray, trials: np.ndarray, lo: float, hi: float) -> float:
    """CE update of a Bernoulli's probability: weighted events over weighted trials of the
    elite, clipped to ``[lo, hi]`` (``lo`` at or below the nominal keeps every event
    drawable); ``lo`` when the elite had no trial."""
    den = float(np.sum(w * trials))
    return float(np.clip(np.sum(w * events) / den, lo, hi)) if den > 0 else lo


def ce_theta(w: np.ndarray, sum_u: np.ndarray, count: np.ndarray) -> float:
    """CE update of a truncated exponential's ``theta``: the fit to the elite's weighted mean
    of the values drawn (``sum_u``: each sample's sum of its ``count`` draws); 0 with none."""
    den = float(np.sum(w * count))
    return exponential_fit(float(np.sum(w * sum_u)) / den) if den > 0 else 0.0
