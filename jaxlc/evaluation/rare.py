"""Rare-event estimators of a failure probability per lane change: crude Monte Carlo and
importance sampling (IS) with a proposal fitted by the cross-entropy (CE) method.

Every random decision of the simulator is a uniform number ``u`` in [0, 1) read in one of two
ways, so a proposal is a change of those uniforms alone (``jaxlc.evaluation.proposal`` applies
it to the traffic):

- an event ``u < p`` (a braking event starts, the lag yields): ``tilt_bernoulli`` draws it with
  probability ``q`` instead; the likelihood ratio of a draw is ``p/q`` where it fires and
  ``(1-p)/(1-q)`` where not;
- a value ``lo + u (hi - lo)`` (a deceleration, a duration): ``tilt_exponential`` draws ``u``
  from the truncated exponential ``theta e^(theta u) / (e^theta - 1)`` on [0, 1), ratio
  ``1 / density``; ``theta = 0`` is the uniform itself.

A lane change's ratio is the product of the ratios of the draws it used, accumulated as a sum
of logs; ``q = p`` and ``theta = 0`` give log ratios of exactly 0. A defensive mixture draws a
share ``alpha`` of the sample from the nominal and the rest from the tilt, each weighted by
``defensive`` (at most ``1 / alpha``; docs/decisions.md, "the defensive mixture"): the toy
check (``toy_sample``, ``toy_estimate``) picks each sample's component at random, the
simulator's IS (``jaxlc.evaluation.validation``) whole chunks in the share ``alpha``. The IS
estimate
``mean(w * failed)`` is unbiased for any proposal that can draw every failure (no
self-normalisation), its interval the normal one of the weighted sample, and the mean weight
``mean(w)``, whose expectation is 1, is its check. Crude MC counts failures, with the
Clopper-Pearson interval of ``jaxlc.evaluation.heldout``. Pure numpy/scipy except the tilts.
"""

from __future__ import annotations

import math
from typing import Any

import jax.numpy as jnp
import numpy as np
import scipy.stats
from jax import Array

from jaxlc.evaluation.heldout import clopper_pearson, upper_bound
from jaxlc.evaluation.stats import CONFIDENCE

Z = float(scipy.stats.norm.ppf(0.5 + CONFIDENCE / 2))  # 1.96
ONE_BELOW = float(np.nextafter(np.float32(1.0), np.float32(0.0)))
THETA_MAX = 30.0  # |theta| of a truncated exponential tilt (mass ~e^-30 at the other end)
# The nominal's share of the toy check's defensive mixture: every weight at most 1 / DEFENSIVE.
DEFENSIVE = 0.1
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


def defensive(log_r: Array, alpha: Array) -> Array:
    """Log weight of a draw from the defensive mixture ``alpha nominal + (1 - alpha) tilted``
    (Hesterberg 1995), given ``log_r``, its log ratio nominal / tilted: ``1 / (alpha + (1 -
    alpha) e^-log_r)``, at most ``1 / alpha``; ``alpha = 0`` gives ``log_r`` itself. Numpy in
    (float64), numpy out."""
    xp = np if isinstance(log_r, np.ndarray) else jnp
    return -xp.logaddexp(xp.log(alpha), xp.log1p(-alpha) - log_r)


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


def mc_estimate(failures: int, n: int) -> dict[str, Any]:
    """Crude Monte Carlo: ``failures`` of ``n`` lane changes, Clopper-Pearson 95%."""
    lo, hi = clopper_pearson(failures, n)
    p = failures / n if n else math.nan
    half = 0.5 * (hi - lo)
    return {
        "estimate": p,
        "lo": lo,
        "hi": hi,
        "upper_bound": upper_bound(failures, n),
        "rel_halfwidth": half / p if p > 0 else math.inf,
        "failures": int(failures),
        "ess": float(n),
        "lane_changes": int(n),
    }


def is_estimate(log_w: np.ndarray, failed: np.ndarray) -> dict[str, Any]:
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
    return _weighted_summary(p, se, y, failed, n, w)


def _weighted_summary(
    p: float, se: float, y: np.ndarray, failed: np.ndarray, lane_changes: int, w: np.ndarray
) -> dict:
    """The estimate ``p`` with standard error ``se`` as the estimators' common dict: ``y`` the
    failures' weighted terms (the ESS's), ``w`` every sample's weight (its mean's interval)."""
    n = w.size
    w_se = float(w.std(ddof=1) / math.sqrt(n)) if n > 1 else math.nan
    mean_w = float(w.mean()) if n else math.nan
    return {
        "estimate": p,
        "lo": max(p - Z * se, 0.0),
        "hi": p + Z * se,
        "upper_bound": p + float(scipy.stats.norm.ppf(CONFIDENCE)) * se if y.any() else math.nan,
        "rel_halfwidth": Z * se / p if p > 0 else math.inf,
        "failures": int(failed.sum()),
        "ess": float(y.sum() ** 2 / (y**2).sum()) if y.any() else 0.0,
        "lane_changes": int(lane_changes),
        "mean_weight": mean_w,
        "mean_weight_lo": mean_w - Z * w_se,
        "mean_weight_hi": mean_w + Z * w_se,
    }


def is_ratio_estimate(log_w: np.ndarray, perf: np.ndarray, failed: np.ndarray) -> dict:
    """IS per lane change when the proposal also changes which cases become lane changes:
    ``sum(w f) / sum(w perf)`` over every case started (``failed`` implies ``perf``), the
    delta method's normal 95% interval; consistent, not unbiased (its bias is O(1/n))."""
    log_w = np.asarray(log_w, np.float64)
    perf, failed = np.asarray(perf, bool), np.asarray(failed, bool) & np.asarray(perf, bool)
    w = np.exp(log_w)
    num, den = np.where(failed, w, 0.0), np.where(perf, w, 0.0)
    p = float(num.sum() / den.sum()) if den.sum() > 0 else math.nan
    se = float(np.sqrt(np.sum((num - p * den) ** 2)) / den.sum()) if den.sum() > 0 else math.nan
    return _weighted_summary(p, se, num, failed, int(perf.sum()), w)


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


# The toy check: ``TOY_D`` events of probability ``TOY_P`` each, a failure when at least
# ``TOY_K`` fire; its probability is the binomial tail, 8.39e-7.
TOY_D, TOY_P, TOY_K = 100, 0.01, 9


def toy_truth() -> float:
    return float(scipy.stats.binom.sf(TOY_K - 1, TOY_D, TOY_P))


def toy_sample(key: Array, n: int, q: float, alpha: float = DEFENSIVE) -> tuple[Array, Array]:
    """``(log_w, events)`` ``(n,)`` of ``n`` toy samples from the defensive mixture of the
    nominal and the tilt to event probability ``q``."""
    import jax

    k_mix, k_u = jax.random.split(key)
    p, q = jnp.float32(TOY_P), jnp.float32(q)
    nominal = jax.random.uniform(k_mix, (n, 1)) < alpha
    u = tilt_bernoulli(jax.random.uniform(k_u, (n, TOY_D)), p, jnp.where(nominal, p, q))
    log_r = bernoulli_log_ratio(u, p, q).sum(axis=1)
    return defensive(log_r, jnp.float32(alpha)), (u < p).sum(axis=1)


def toy_estimate(key: Array, n: int, pilot: int = 1000, rounds: int = 6) -> dict[str, Any]:
    """CE on ``pilot``-sample batches from the nominal ``q = p``, then IS from ``n`` samples."""
    import jax

    q = TOY_P
    keys = jax.random.split(key, rounds + 1)
    for k in keys[:rounds]:
        log_w, events = (np.asarray(a) for a in toy_sample(k, pilot, q))
        w, level = elite(log_w, events >= TOY_K, events)
        q = ce_rate(w, events, np.full(events.shape, TOY_D), TOY_P, 0.5)
        if level == math.inf:
            break
    log_w, events = (np.asarray(a) for a in toy_sample(keys[-1], n, q))
    return {**is_estimate(log_w, events >= TOY_K), "q": q, "truth": toy_truth()}
